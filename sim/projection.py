"""Local tangent-plane coordinates around an origin (metres north/east of it).

The vehicle model flies in this plane; positions cross the boundary as lat/lon.
An equirectangular projection is exact on the round trip and within centimetres of
the great-circle distance over the few kilometres a field covers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dronefleet.schemas.geo import EARTH_RADIUS_M

_M_PER_DEG = EARTH_RADIUS_M * math.pi / 180.0


@dataclass(frozen=True)
class LocalFrame:
    lat0: float
    lon0: float

    def to_local(self, lat: float, lon: float) -> tuple[float, float]:
        north = (lat - self.lat0) * _M_PER_DEG
        east = (lon - self.lon0) * _M_PER_DEG * math.cos(math.radians(self.lat0))
        return north, east

    def to_global(self, north: float, east: float) -> tuple[float, float]:
        lat = self.lat0 + north / _M_PER_DEG
        lon = self.lon0 + east / (_M_PER_DEG * math.cos(math.radians(self.lat0)))
        return lat, lon
