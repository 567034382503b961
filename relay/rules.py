"""The relay's separation rules in one place (issue 78): pure values, no I/O.

Every clearance the relay's planner keeps (relay/chain.py, relay/ways.py,
mission/script/relaying.py, the bundled plugin) derives from the one separation two
flying drones must keep, the plugin's `min_separation` input, plus what flight adds to
it: the way a drone covers before a hold takes effect, and how far flight strays from
a spot. Built once per mission from the plugin's inputs and passed to each part; a
part that read a constant of its own would keep 5 m when the operator asked for 10.
"""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_SEPARATION_M = 5.0


@dataclass(frozen=True)
class Separation:
    separation_m: float = DEFAULT_SEPARATION_M  # two flying drones never come closer (3-D)
    reaction_m: float = 3.0  # what a worker flies before a hold takes effect: a second at its speed
    stray_m: float = 0.5  # how far a hovering drone strays from its spot
    level_band_m: float = 2.0  # a relay this near its duty level is on it (not crossing the levels)

    def __post_init__(self) -> None:
        if not self.separation_m > 0:
            raise ValueError(f"min_separation must be above 0 m, got {self.separation_m:g}")

    @property
    def way_m(self) -> float:
        """From another worker's way, a relay's column, or a relay coming down: the
        separation plus the way flown before a hold takes effect (8 m at 5)."""
        return self.separation_m + self.reaction_m

    @property
    def around_m(self) -> float:
        """From where another drone hovers: the separation plus its stray (5.5 m at 5)."""
        return self.separation_m + self.stray_m

    @property
    def parked_m(self) -> float:
        """Across from a drone on the ground, which may take off (6 m at 5): a held
        drone is not held over it, a relay lands no nearer, and none climbs from under
        a way flown."""
        return self.separation_m + 2 * self.stray_m

    @property
    def relays_apart_m(self) -> float:
        """Between relays' spots on one level (7 m at 5): both may stray, each by a
        level band's worth as it comes down onto it."""
        return self.separation_m + self.level_band_m

    @property
    def level_gap_m(self) -> float:
        """Between the levels relays fly out and home on, and from the duty level to the
        served drones' highest (6 m at 5)."""
        return self.parked_m


DEFAULT = Separation()
