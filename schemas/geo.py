"""Great-circle maths on (lat, lon) in degrees: thesis equations 4.1–4.3.

bearing (4.1), haversine distance (4.2) and the destination point given a bearing
and a distance (4.3), plus the small helpers the agent, the simulator and missions
share. Pure functions; distances in metres, angles in degrees, 0 = north, clockwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6_371_000.0


def normalize_deg(angle: float) -> float:
    """An angle folded into [0, 360)."""
    folded = math.fmod(angle, 360.0)
    return folded + 360.0 if folded < 0 else folded


def angle_diff_deg(a: float, b: float) -> float:
    """Signed smallest rotation from b to a, in (-180, 180]."""
    d = normalize_deg(a - b)
    return d - 360.0 if d > 180.0 else d


def bearing_deg(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Initial bearing from point 1 towards point 2 (eq. 4.1)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dlon = math.radians(lon2 - lon1)
    y = math.sin(dlon) * math.cos(p2)
    x = math.cos(p1) * math.sin(p2) - math.sin(p1) * math.cos(p2) * math.cos(dlon)
    return normalize_deg(math.degrees(math.atan2(y, x)))


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Haversine ground distance (eq. 4.2)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    h = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(
        math.radians(lon2 - lon1) / 2
    ) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(h)))


def destination(lat: float, lon: float, dist_m: float, bearing: float) -> tuple[float, float]:
    """The point `dist_m` away from (lat, lon) along `bearing` (eq. 4.3)."""
    p1, l1 = math.radians(lat), math.radians(lon)
    b = math.radians(bearing)
    d = dist_m / EARTH_RADIUS_M
    p2 = math.asin(math.sin(p1) * math.cos(d) + math.cos(p1) * math.sin(d) * math.cos(b))
    l2 = l1 + math.atan2(
        math.sin(b) * math.sin(d) * math.cos(p1), math.cos(d) - math.sin(p1) * math.sin(p2)
    )
    return math.degrees(p2), (math.degrees(l2) + 540.0) % 360.0 - 180.0


def offset_body(
    lat: float, lon: float, heading: float, right_m: float, forward_m: float
) -> tuple[float, float]:
    """The point `forward_m` ahead and `right_m` to the right of a vehicle facing `heading`."""
    dist = math.hypot(right_m, forward_m)
    if dist == 0:
        return lat, lon
    return destination(lat, lon, dist, heading + math.degrees(math.atan2(right_m, forward_m)))


@dataclass(frozen=True)
class Box:
    """A box of the map: S, W, N, E in degrees."""

    south: float
    west: float
    north: float
    east: float

    @classmethod
    def parse(cls, text: str) -> Box:
        """`S,W,N,E` in degrees."""
        try:
            s, w, n, e = (float(v) for v in text.split(","))
        except ValueError:
            raise ValueError(f"--bbox takes S,W,N,E in degrees (e.g. 40.63,-8.67,40.65,-8.65), not {text!r}") from None
        if not (-85.06 <= s < n <= 85.06 and -180 <= w < e <= 180):
            raise ValueError(f"--bbox {text}: south below north, west below east, within ±85° and ±180°")
        return cls(s, w, n, e)
