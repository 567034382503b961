"""The ground station: router, fleet registry, event log, HTTP API (SPEC §4)."""
