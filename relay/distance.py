"""The thesis's distance-only relay (scripts 5.9–5.13), kept as the baseline the
measured mode is compared against (`enable("relay", mode="distance", target_dist=…)`).

One chain per drone: when a drone's move takes it beyond `target_dist` from the ground
station, a relay is dispatched to follow it; relays are drones of the mission too, so a
relay that in turn goes beyond `target_dist` gets its own follower. Pure functions in
the planner's local frame (metres north/east of the ground station at (0, 0)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from dronefleet.relay.placement import Point, dist, toward

GROUND: Point = (0.0, 0.0)
MAX_SPEED = 10.0  # m/s: a follower never flies faster (script 5.13)
CLEAR_MARGIN_M = 1.0  # keep_clear keeps this much more than min_separation (flight is not exact)
CLEAR_PASSES = 6


def takeoff_time(n_relays: int) -> float:
    """Script 5.11: the seconds a new relay needs before it is useful (the higher
    altitude, every other relay, takes longer)."""
    return 15.0 if n_relays % 2 == 0 else 10.0


def requires_relay(at: Point, goal: Point | None, speed: float, n_relays: int, target_dist: float) -> bool:
    """Script 5.11: its move goes beyond target_dist, and by the time a relay is up it
    would be past 75 % of it."""
    return (goal is not None and dist(goal, GROUND) > target_dist
            and dist(at, GROUND) + takeoff_time(n_relays) * speed > 0.75 * target_dist)


def moving_further(at: Point, goal: Point | None) -> bool:
    """Script 5.10: running a move whose target is further from the ground than it is."""
    return goal is not None and dist(at, GROUND) < dist(goal, GROUND)


def returning(at: Point, goal: Point | None, target_dist: float) -> bool:
    """Script 5.10: not moving further, and within target_dist of the ground."""
    return not moving_further(at, goal) and dist(at, GROUND) < target_dist


def new_target(other: Point, other_goal: Point | None, me: Point, target_dist: float) -> Point:
    """Script 5.12: halfway to the ground while the followed drone moves away and is
    between half and all of target_dist from me; stay while it is nearer; otherwise
    target_dist from it, toward the ground."""
    d = dist(me, other)
    if d < target_dist and moving_further(other, other_goal):
        if d > target_dist / 2:
            return toward(other, GROUND, dist(other, GROUND) / 2)
        return me
    return toward(other, GROUND, target_dist)


def keep_clear(spot: Point, alt: float, others: Sequence[tuple[Point, float]], min_separation: float) -> Point:
    """Not in the thesis (it had no separation): `spot` at `alt`, moved away from each
    drone of `others` (point, altitude) it would come within `min_separation` of, in
    3-D, by just enough (plus CLEAR_MARGIN_M); a few passes settle crowded spots."""
    for _ in range(CLEAR_PASSES):
        near = [(p, a) for p, a in others if math.hypot(dist(p, spot), a - alt) < min_separation + CLEAR_MARGIN_M]
        if not near:
            break
        p, a = min(near, key=lambda o: math.hypot(dist(o[0], spot), o[1] - alt))
        flat = math.sqrt(max((min_separation + CLEAR_MARGIN_M) ** 2 - (a - alt) ** 2, 0.0)) + 0.1
        away = _unit(p, spot) or _unit(p, GROUND) or (1.0, 0.0)  # right above or below it: aside, toward the ground
        spot = (p[0] + away[0] * flat, p[1] + away[1] * flat)
    return spot


def _unit(a: Point, b: Point) -> Point | None:
    d = dist(a, b)
    return ((b[0] - a[0]) / d, (b[1] - a[1]) / d) if d > 1e-6 else None


def new_speed(other_speed: float) -> float:
    """Script 5.13: relative to the followed drone's speed, at most 10 m/s."""
    return min(MAX_SPEED, max(1.0, other_speed * 1.2))


def new_bearing(other: Point, other_goal: Point | None, me: Point) -> float:
    """Script 5.13: facing the followed drone while it moves away, else the ground."""
    look = other if moving_further(other, other_goal) else GROUND
    return math.degrees(math.atan2(look[1] - me[1], look[0] - me[0])) % 360.0
