"""Missions: the DSL and its checks, the sandbox and limits, assignment, plugins, task
bundles, preflight, QGroundControl plans, units, safety, sensors and kinds, the thesis's experiments."""
