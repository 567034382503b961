"""Relays (SPEC §8): where relay drones go, on measured link quality (`relay.placement`),
and the thesis's distance-only baseline (`relay.distance`). Pure code: no I/O, no clock."""
