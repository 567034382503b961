"""The on-drone agent: bridges a flight controller to the Zenoh mesh with the
thesis's command semantics (priority, status tracking, system events)."""
