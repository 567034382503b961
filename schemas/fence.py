"""The geofence (SPEC §11) as pure geometry, checked at both ends: the ground refuses a
command that would leave it (409 `geofence`), the agent refuses it too (reason
`geofence`) whatever path the command came by, and turns home a drone found outside.

    geofence:
      polygon: [[40.6345, -8.6612], [40.6345, -8.6590], [40.6325, -8.6590], [40.6325, -8.6612]]
      max_alt_m: 120          # above home
      min_separation_m: 5     # between drones' targets (the ground's deconfliction; the relay plugin keeps its own `min_separation` input)

A flight is judged on its straight path, in a local plane around the fence (the
fences of a field are a few km at most): it must end inside the polygon and never
cross its border on the way, so a path between two inside points that cuts across a
concave corner is refused. A drone outside may fly back in (the first crossing is the
way in); `return` is never checked, it is the way home.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
from msgspec import Meta

from dronefleet.schemas.commands import Command, Goto, Move, Takeoff
from dronefleet.schemas.geo import EARTH_RADIUS_M, offset_body
from dronefleet.schemas.telemetry import Position

REASON = "geofence"
CONFLICT = "conflict"  # the ground's 409 for a target within min_separation_m of another drone's
Vertex = tuple[Annotated[float, Meta(ge=-90, le=90)], Annotated[float, Meta(ge=-180, le=180)]]
_Point = tuple[float, float]


class Geofence(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    polygon: list[Vertex] = msgspec.field(default_factory=list)  # [[lat, lon], …]; empty: no horizontal limit
    max_alt_m: Annotated[float, Meta(gt=0, le=10_000)] | None = None  # above home
    min_separation_m: Annotated[float, Meta(ge=0, le=1000)] = 5.0  # between drones' targets and hovering drones

    def __post_init__(self) -> None:
        if self.polygon and len(self.polygon) < 3:
            raise ValueError(f"geofence.polygon needs at least 3 vertices [lat, lon], got {len(self.polygon)}")
        if self.polygon and abs(_area(self._plane())) < 1.0:
            raise ValueError("geofence.polygon encloses no area (its vertices are on one line)")

    @property
    def limits(self) -> bool:
        """Whether it limits anything (an empty fence only sets min_separation_m)."""
        return bool(self.polygon) or self.max_alt_m is not None

    def _origin(self) -> _Point:
        return self.polygon[0]

    def _local(self, lat: float, lon: float) -> _Point:
        lat0, lon0 = self._origin()
        k = math.pi / 180 * EARTH_RADIUS_M
        return (lat - lat0) * k, (lon - lon0) * k * math.cos(math.radians(lat0))

    def _plane(self) -> list[_Point]:
        return [self._local(lat, lon) for lat, lon in self.polygon]

    def inside(self, lat: float, lon: float) -> bool:
        """Within the polygon (on its border counts as inside); always, without one."""
        return not self.polygon or _contains(self._plane(), self._local(lat, lon))

    def check(self, start: _Point | None, end: _Point, end_alt_above_home: float | None) -> str | None:
        """Why flying straight from `start` (lat, lon; None: not known) to `end` at
        `end_alt_above_home` breaks the fence, or None."""
        if self.max_alt_m is not None and end_alt_above_home is not None and end_alt_above_home > self.max_alt_m + 1e-6:
            return f"{REASON}: the target is {end_alt_above_home:.1f} m above home, over max_alt_m {self.max_alt_m:g} m"
        if not self.polygon:
            return None
        poly = self._plane()
        b = self._local(*end)
        if not _contains(poly, b):
            return f"{REASON}: the target {end[0]:.6f}, {end[1]:.6f} is outside the fence"
        if start is None:
            return None
        a = self._local(*start)
        # Split the path where it crosses the border; every piece after the first one
        # inside must be inside too (a drone outside may come in, not go out again).
        cuts = sorted({0.0, 1.0, *(t for p, q in _edges(poly) if (t := _crossing(a, b, p, q)) is not None)})
        entered = False
        for t0, t1 in zip(cuts, cuts[1:], strict=False):
            if t1 - t0 < 1e-9:
                continue
            mid = (t0 + t1) / 2
            piece_in = _contains(poly, (a[0] + (b[0] - a[0]) * mid, a[1] + (b[1] - a[1]) * mid))
            if entered and not piece_in:
                return f"{REASON}: the straight path to the target leaves the fence"
            entered = entered or piece_in
        return None

    def outside(self, lat: float, lon: float, alt_above_home: float | None) -> str | None:
        """Why a drone at this spot is outside the fence, or None."""
        if self.max_alt_m is not None and alt_above_home is not None and alt_above_home > self.max_alt_m + FOUND_OUTSIDE_MARGIN_M:
            return f"{alt_above_home:.1f} m above home, over max_alt_m {self.max_alt_m:g} m"
        if self.polygon and not self.inside(lat, lon):
            return f"at {lat:.6f}, {lon:.6f}, outside the fence's polygon"
        return None


FOUND_OUTSIDE_MARGIN_M = 2.0  # a climb that overshoots the ceiling a little is not "outside"


class Flight(msgspec.Struct, frozen=True):
    """Where a command takes a drone: from `start` (lat, lon; None if unknown) to `end`
    at `alt` m above home (None if unknown)."""

    start: _Point | None
    end: _Point
    alt: float | None


def flight_of(cmd: Command, position: Position | None, heading: float, takeoff_alt: float | None = None) -> Flight | None:
    """The flight a takeoff, goto or move asks for, from the drone's `position` and
    `heading`; None for commands that take it nowhere new (return, land, cancel, turn,
    offboard setpoints: the agent's watch turns home a drone they take outside)."""
    here = (position.lat, position.lon) if position is not None else None
    home_alt = position.alt - position.rel_alt if position is not None else None
    match cmd:
        case Takeoff():
            alt = cmd.alt if cmd.alt is not None else takeoff_alt
            return Flight(here, here, alt) if here is not None else None
        case Goto():
            if cmd.alt is not None:
                alt = cmd.alt - home_alt if home_alt is not None else None
            else:
                alt = position.rel_alt if position is not None else None
            return Flight(here, (cmd.lat, cmd.lon), alt)
        case Move():
            if position is None or here is None:
                return None
            return Flight(here, offset_body(position.lat, position.lon, heading, cmd.x, cmd.y), position.rel_alt + cmd.z)
    return None


def refusal(fence: Geofence, cmd: Command, position: Position | None, heading: float,
            takeoff_alt: float | None = None) -> str | None:
    """Why `fence` refuses `cmd` for a drone at `position`, or None."""
    if not fence.limits:
        return None
    flight = flight_of(cmd, position, heading, takeoff_alt)
    return fence.check(flight.start, flight.end, flight.alt) if flight is not None else None


def _edges(poly: list[_Point]) -> list[tuple[_Point, _Point]]:
    return list(zip(poly, poly[1:] + poly[:1], strict=True))


def _area(poly: list[_Point]) -> float:
    return sum(p[0] * q[1] - q[0] * p[1] for p, q in _edges(poly)) / 2


def _contains(poly: list[_Point], pt: _Point) -> bool:
    """Ray casting, with the border counted inside (within 1 cm)."""
    x, y = pt
    inside = False
    for (x1, y1), (x2, y2) in _edges(poly):
        if _on_segment(pt, (x1, y1), (x2, y2)):
            return True
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def _on_segment(pt: _Point, p: _Point, q: _Point, tol: float = 0.01) -> bool:
    dx, dy = q[0] - p[0], q[1] - p[1]
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((pt[0] - p[0]) * dx + (pt[1] - p[1]) * dy) / length2))
    return math.hypot(p[0] + t * dx - pt[0], p[1] + t * dy - pt[1]) <= tol


def _crossing(a: _Point, b: _Point, p: _Point, q: _Point) -> float | None:
    """Where along a→b (0..1) it meets the edge p→q, or None."""
    rx, ry = b[0] - a[0], b[1] - a[1]
    sx, sy = q[0] - p[0], q[1] - p[1]
    denom = rx * sy - ry * sx
    if abs(denom) < 1e-12:
        return None  # parallel: touching along an edge is on the border, inside
    t = ((p[0] - a[0]) * sy - (p[1] - a[1]) * sx) / denom
    u = ((p[0] - a[0]) * ry - (p[1] - a[1]) * rx) / denom
    return t if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0 else None
