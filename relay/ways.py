"""Keeping leashed drones out of each other's way (issue 32): pure code, no I/O.

The leash (relay/chain.py) decides how far a worker's goto may go for its radio link;
this decides how far it may go without passing another drone. Workers of one mission
take off side by side and set out in different directions, so their straight ways
crossed near the laptop: in the corpus, 20 of 200 worlds had two flying drones closer
than 5 m, most of them two workers setting out. A way is declared when it is flown:

- a worker's next leg (from where it is, toward where the leash lets it go) is cut
  short where it would come within the rules' way clearance (`Separation.way_m`, 3-D) of another worker's remaining declared
  leg or of the column above a worker that has not taken off yet (it will climb
  there), or within `Separation.around_m` of where any other drone is now (relays keep their own
  levels: relay/chain.py), or within the way clearance of the column of a relay sent from the
  ground or not yet above the worker's level, which climbs (or lands) through it (a
  worker flew over a spare as it took off, 3.1 m from it);
- cut to nothing, the worker waits where it is; the other drone's way clears as it
  flies (its remaining leg is from where it is now);
- a worker already closer than that to another (they take off side by side) may fly
  any way that does not bring it closer still;
- two workers each waiting on the other: the first by name goes; a worker kept waiting
  YIELD_LIMIT_S goes too. Either still keeps the around clearance from where every drone is, and
  the way clearance from the way of one that set out meanwhile (two kept waiting as long went in
  the same second and crossed 2.6 m apart); the later by name, if it still
  cannot move, steps aside out of the other's way.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

from dronefleet.relay.rules import Separation

Point3 = tuple[float, float, float]  # metres north, east, up (above the laptop's level)

AIRBORNE_M = 1.0
YIELD_LIMIT_S = 20.0
FRESH_LEG_S = 2.0  # a way declared this lately is kept off even by a worker kept waiting
SEARCH_STEPS = 12  # halvings of the leg when looking for its clear part
MIN_LEG_M = 3.0  # a leg cut shorter than this does not get the drone anywhere (the leash sends legs of 2 m or more)
NEAR_SLACK_M = 1e-6  # a drone already nearer than it should be may fly a leg this much nearer (rounding), no more: it crept 1 cm a tick


def _sub(a: Point3, b: Point3) -> Point3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a: Point3, b: Point3) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _along(a: Point3, b: Point3, t: float) -> Point3:
    return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2]))


def _to_segment(p: Point3, a: Point3, b: Point3) -> float:
    """The least distance from point p to segment a-b."""
    d = _sub(b, a)
    length2 = _dot(d, d)
    t = 0.0 if length2 <= 1e-12 else min(1.0, max(0.0, _dot(_sub(p, a), d) / length2))
    return math.dist(p, _along(a, b, t))


def segment_distance(p1: Point3, q1: Point3, p2: Point3, q2: Point3) -> float:
    """The least distance between segments p1-q1 and p2-q2 (either may be a point)."""
    d1, d2, r = _sub(q1, p1), _sub(q2, p2), _sub(p1, p2)
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    eps = 1e-15  # a way this short (3e-8 m) is a point
    if a <= eps and e <= eps:
        return math.dist(p1, p2)
    if a <= eps:
        s, t = 0.0, min(1.0, max(0.0, f / e))
    else:
        c = _dot(d1, r)
        if e <= eps:
            s, t = min(1.0, max(0.0, -c / a)), 0.0
        else:
            b = _dot(d1, d2)
            denom = a * e - b * b
            if denom <= 1e-9 * a * e:  # (nearly) parallel: the nearest points include an end of one
                return min(_to_segment(p1, p2, q2), _to_segment(q1, p2, q2), _to_segment(p2, p1, q1),
                           _to_segment(q2, p1, q1))
            s = min(1.0, max(0.0, (b * f - c * e) / denom))
            t = (b * s + f) / e
            if t < 0.0:
                s, t = min(1.0, max(0.0, -c / a)), 0.0
            elif t > 1.0:
                s, t = min(1.0, max(0.0, (b - c) / a)), 1.0
    return math.dist(_along(p1, q1, s), _along(p2, q2, t))


def closest_approach(a0: Point3, a1: Point3, b0: Point3, b1: Point3) -> float:
    """The least distance between two drones over one interval in which each flies
    straight at constant speed, from a0 to a1 and from b0 to b1: the closest approach
    in continuous time, which samples at the interval's ends can miss (two drones
    crossing between two samples)."""
    r0 = _sub(a0, b0)
    dr = _sub(_sub(a1, a0), _sub(b1, b0))
    speed2 = _dot(dr, dr)
    s = 0.0 if speed2 <= 1e-12 else min(1.0, max(0.0, -_dot(r0, dr) / speed2))
    return math.hypot(r0[0] + s * dr[0], r0[1] + s * dr[1], r0[2] + s * dr[2])


LAND_RATE_MPS = 1.0  # a relay's descent is judged at this rate: slower than either autopilot lands, the longer window


def descent_clear(column: Point3, below: Collection[tuple[Point3, tuple[float, float]]], clear_m: float) -> bool:
    """Whether a drone at `column` (north, east, up) may come straight down now: every
    drone of `below` (where it is, its velocity north and east in m/s) flying under it
    keeps `clear_m` across from the column while the descent lasts (judged at
    LAND_RATE_MPS), flying straight on at its velocity. A snapshot is not enough: a
    worker flying home at 5 m/s, 130 m out when a relay began its 30-s descent, passed
    2.5 m from its column under it."""
    x0, y0, z0 = column
    lasts_s = max(0.0, z0 - AIRBORNE_M) / LAND_RATE_MPS
    top = (x0, y0, 0.0)
    for (x, y, z), (vn, ve) in below:
        if z <= AIRBORNE_M or z >= z0:
            continue  # on the ground, or above it: not in the way down
        ahead = (x + vn * lasts_s, y + ve * lasts_s, 0.0)
        if segment_distance((x, y, 0.0), ahead, top, top) < clear_m:
            return False
    return True


@dataclass
class Ways:
    legs: dict[str, tuple[Point3, Point3]] = field(default_factory=dict)  # drone → its declared leg
    flown: set[str] = field(default_factory=set)  # workers seen in the air
    waiting: dict[str, float] = field(default_factory=dict)  # worker → since when it waits for another
    wants: dict[str, Point3] = field(default_factory=dict)  # worker → where its leg would go, all of it
    declared: dict[str, float] = field(default_factory=dict)  # worker → when its leg was last declared
    gives_way: dict[str, str] = field(default_factory=dict)  # worker → the drone it waits for now
    rules: Separation = field(default_factory=Separation)

    def clear(self, drone: str, at: Point3, to: Point3, others: Mapping[str, Point3], workers: set[str],
              now: float, relays: Collection[str] = (), launching: bool = False) -> tuple[Point3, str | None]:
        """How far `drone` may fly from `at` toward `to`: the end of its clear part, and
        the drone it gives way to (None when it may fly all of it). `others`: where
        every other drone is; `workers`: the leashed drones (their legs are declared);
        `relays`: drones sent as relays (one still on the ground is about to take off);
        `launching`: a relay is asked for and not assigned yet (any drone on the ground
        may be the one: a worker's leg was laid over a spare as it was assigned)."""
        self.wants[drone] = to
        top = max(at[2], to[2])
        obstacles: list[tuple[str, Point3, Point3, float, bool]] = []  # (drone, from, to, clearance, a way)
        for o, p in others.items():
            if o == drone:
                continue
            airborne = p[2] > AIRBORNE_M
            if o not in workers and (p[2] < top + self.rules.around_m if airborne else o in relays or launching):
                # a relay below the top of this leg (taking off or landing), or on the ground
                # and sent or about to be (it climbs next): its column
                obstacles.append((o, (p[0], p[1], 0.0), (p[0], p[1], top + self.rules.around_m), self.rules.way_m, False))
            elif airborne:
                obstacles.append((o, p, p, self.rules.way_m if o in workers else self.rules.around_m, False))
                if o in workers:
                    self.flown.add(o)
                    leg = self.legs.get(o)
                    if leg is not None:
                        obstacles.append((o, p, leg[1], self.rules.way_m, True))  # what is left of its leg
            elif o in workers and o not in self.flown:
                obstacles.append((o, (p[0], p[1], 0.0), (p[0], p[1], top), self.rules.way_m, False))
            else:
                self.legs.pop(o, None)  # landed: its way is flown
        # Already closer than that (workers take off side by side): not closer still.
        near = [min(clear, segment_distance(at, at, a, b) - NEAR_SLACK_M) for _, a, b, clear, _ in obstacles]

        def blocker(t: float, relaxed: bool) -> str | None:
            end = _along(at, to, t)
            for (o, a, b, _, way), clear in zip(obstacles, near, strict=True):
                if relaxed and way and (o in self.waiting or now - self.declared.get(o, -math.inf) > FRESH_LEG_S):
                    continue  # its way waits too, or is old; one that just set out is kept off
                if segment_distance(at, end, a, b) < (min(clear, self.rules.around_m) if relaxed and not way else clear):
                    return o
            return None

        first = blocker(1.0, False)
        if first is None:
            self.waiting.pop(drone, None)
            self.gives_way.pop(drone, None)
            self._declare(drone, (at, to), now)
            return to, None
        # Two drones each waiting on the other: the first by name goes; anyone kept
        # waiting YIELD_LIMIT_S goes too. Either keeps the around clearance from where others are.
        since = self.waiting.setdefault(drone, now)
        relaxed = (first in self.waiting and drone < first) or now - since >= YIELD_LIMIT_S
        self.gives_way[drone] = first
        if relaxed and blocker(1.0, True) is None:
            self.waiting.pop(drone, None)
            self.gives_way.pop(drone, None)
            self._declare(drone, (at, to), now)
            return to, first
        lo, hi = 0.0, 1.0
        for _ in range(SEARCH_STEPS):
            mid = (lo + hi) / 2
            if blocker(mid, relaxed) is None:
                lo = mid
            else:
                hi = mid
        end = _along(at, to, lo)
        if relaxed and math.dist(at, end) < MIN_LEG_M and drone > first and first in others:
            end = self._aside(at, others[first], self.wants.get(first), others, drone)
        if math.dist(at, end) < MIN_LEG_M and self._first_of_jam(drone):
            end = self._out_of_jam(at, to, obstacles, near)
        self._declare(drone, (at, end), now)
        return end, first

    def _first_of_jam(self, drone: str) -> bool:
        """Whether `drone` waits in a ring of workers each waiting for the next (three
        took off side by side, each in another's way): the first of the ring by name."""
        ring, o = [drone], self.gives_way.get(drone)
        while o is not None and o not in ring:
            ring.append(o)
            o = self.gives_way.get(o)
        return o == drone and drone == min(ring)

    def _out_of_jam(self, at: Point3, to: Point3, obstacles: list[tuple[str, Point3, Point3, float, bool]],
                    near: list[float]) -> Point3:
        """The way out of a ring of waiting workers: a leg of the way clearance, in whichever of 16
        headings comes closer to no drone nor way (what any drone already that near may
        fly), leaving the most room around it up to the way clearance, then getting nearest its
        goal; `at` when none does. The ring's others wait where they are meanwhile."""
        best: tuple[float, float] | None = None
        end = at
        for k in range(16):
            a = 2 * math.pi * k / 16
            p = (at[0] + self.rules.way_m * math.cos(a), at[1] + self.rules.way_m * math.sin(a), at[2])
            if any(segment_distance(at, p, b0, b1) < clear for (_, b0, b1, _, _), clear in zip(obstacles, near, strict=True)):
                continue
            room = min([segment_distance(p, p, b0, b1) for _, b0, b1, _, _ in obstacles] + [self.rules.way_m])
            key = (round(room, 1), -math.dist(p, to))
            if best is None or key > best:
                best, end = key, p
        return end

    def _declare(self, drone: str, leg: tuple[Point3, Point3], now: float) -> None:
        self.legs[drone] = leg
        self.declared[drone] = now

    def _aside(self, at: Point3, other: Point3, wants: Point3 | None, others: Mapping[str, Point3],
               drone: str) -> Point3:
        """Two drones that took off side by side and each want to pass where the other
        is (else both wait for ever): the later by name steps aside, across the
        way the other wants to go, until that way is the way clearance off; where the other wants
        to go nowhere, away from it. `at` when that step would come near another drone."""
        ox, oy = other[0], other[1]
        dx, dy = ((wants[0] - ox, wants[1] - oy) if wants is not None else (0.0, 0.0))
        length = math.hypot(dx, dy)
        if length < 1.0:  # no way: straight away from it
            ax, ay = at[0] - ox, at[1] - oy
            norm = math.hypot(ax, ay) or 1.0
            step = (ax / norm * self.rules.way_m, ay / norm * self.rules.way_m)
        else:
            ux, uy = dx / length, dy / length
            side = (at[0] - ox) * -uy + (at[1] - oy) * ux  # which side of its way this drone is on
            sign = 1.0 if side >= 0 else -1.0
            across = abs(side)
            step = (-uy * sign * (self.rules.way_m + 1.0 - across), ux * sign * (self.rules.way_m + 1.0 - across)) \
                if across < self.rules.way_m + 1.0 else (0.0, 0.0)
        end = (at[0] + step[0], at[1] + step[1], at[2])
        if any(segment_distance(at, end, p, p) < self.rules.around_m for o, p in others.items() if o != drone and p[2] > AIRBORNE_M
               and math.dist(at, p) >= self.rules.around_m):
            return at
        return end
