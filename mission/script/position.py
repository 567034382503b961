"""Positions in missions: distance, bearing, targets and chained relative moves.

Anything position-like is accepted where a position is expected: a Position, a drone
(its current position), a drone's `cmd` (its target) or `home`, a dict with `lat`,
`lon` and optionally `alt`, or a `(lat, lon[, alt])` tuple. A Position also carries a
heading, so `drone.left(5*m).forward(10*m)` chains relative to where the drone faces.
"""

from __future__ import annotations

import math
from typing import Any

from dronefleet.mission.script.units import angle, length
from dronefleet.schemas.geo import bearing_deg, destination, distance_m, normalize_deg


class Position:
    """lat/lon in degrees, alt in metres AMSL (None: unknown/keep), heading in degrees."""

    __slots__ = ("alt", "heading", "lat", "lon")

    def __init__(self, lat: float, lon: float, alt: float | None = None, heading: float = 0.0) -> None:
        lat, lon = float(lat), float(lon)
        if not (math.isfinite(lat) and -90 <= lat <= 90):
            raise ValueError(f"latitude must be within ±90, got {lat}")
        if not (math.isfinite(lon) and -180 <= lon <= 180):
            raise ValueError(f"longitude must be within ±180, got {lon}")
        self.lat = lat
        self.lon = lon
        self.alt = None if alt is None else length(alt, "alt")
        self.heading = normalize_deg(float(heading))

    def __repr__(self) -> str:
        alt = "" if self.alt is None else f", alt={self.alt:.1f}"
        return f"Position(lat={self.lat:.6f}, lon={self.lon:.6f}{alt})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Position) and (self.lat, self.lon, self.alt) == (other.lat, other.lon, other.alt)

    def __hash__(self) -> int:
        return hash((self.lat, self.lon, self.alt))

    # ---- measures -----------------------------------------------------------------

    def distance(self, other: Any) -> float:
        """Metres over the ground (altitude ignored)."""
        o = as_position(other)
        return distance_m(self.lat, self.lon, o.lat, o.lon)

    def bearing(self, other: Any) -> float:
        """Degrees from north, clockwise, towards `other`."""
        o = as_position(other)
        return bearing_deg(self.lat, self.lon, o.lat, o.lon)

    def target(self, dist: Any, bearing: Any) -> Position:
        lat, lon = destination(self.lat, self.lon, length(dist), angle(bearing, "bearing"))
        return Position(lat, lon, self.alt, self.heading)

    # ---- chained relative positions ----------------------------------------------

    def _offset(self, forward: float, right: float) -> Position:
        d = math.hypot(forward, right)
        if d == 0:
            return self
        return self.target(d, self.heading + math.degrees(math.atan2(right, forward)))

    def forward(self, d: Any) -> Position:
        return self._offset(length(d), 0.0)

    def backward(self, d: Any) -> Position:
        return self._offset(-length(d), 0.0)

    def right(self, d: Any) -> Position:
        return self._offset(0.0, length(d))

    def left(self, d: Any) -> Position:
        return self._offset(0.0, -length(d))

    def up(self, d: Any) -> Position:
        return Position(self.lat, self.lon, (self.alt or 0.0) + length(d), self.heading)

    def down(self, d: Any) -> Position:
        return Position(self.lat, self.lon, (self.alt or 0.0) - length(d), self.heading)


def position(lat: float, lon: float, alt: Any = None) -> Position:
    """The script-level constructor: `position(40.63, -8.66, 20*m)`."""
    return Position(lat, lon, alt)


def as_position(value: Any) -> Position:
    if isinstance(value, Position):
        return value
    as_pos = getattr(type(value), "as_position", None)
    if as_pos is not None:  # drones, commands, homes
        return as_pos(value)
    if isinstance(value, dict):
        try:
            return Position(value["lat"], value["lon"], value.get("alt"), value.get("heading", 0.0))
        except KeyError as exc:
            raise ValueError(f"a position needs lat and lon, missing {exc.args[0]!r}") from None
    if isinstance(value, (tuple, list)) and len(value) in (2, 3):
        return Position(*value)
    raise TypeError(f"expected a position (Position, drone, dict with lat/lon, or (lat, lon)), got {value!r}")


def distance(a: Any, b: Any) -> float:
    return as_position(a).distance(b)


def bearing(a: Any, b: Any) -> float:
    return as_position(a).bearing(b)


def target(origin: Any, dist: Any, bearing: Any) -> Position:
    return as_position(origin).target(dist, bearing)
