"""The agent on the drone (SPEC §2–§3, §8): its command contract and priorities, the
geofence it keeps, its link probes, quality and lost-link policy, neighbours and re-sends."""
