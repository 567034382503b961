"""The web dashboard and planner (SPEC §10) in real Chromium against a real `fleet ground`."""
