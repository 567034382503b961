"""The heat field of thesis example 21, a pure model: an environment temperature plus
heat sources, each a centre, a radius and a centre temperature. Inside a source the
temperature falls linearly from the centre's to the environment's at the radius; with
several sources the hottest wins. The world file (sim/world.py) places sources, the
temperature sensor (sim/sensors.py) reads the field where its drone is."""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta

from dronefleet.schemas.geo import distance_m

Lat = Annotated[float, Meta(ge=-90, le=90)]
Lon = Annotated[float, Meta(ge=-180, le=180)]


class HeatSource(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    lat: Lat
    lon: Lon
    radius: Annotated[float, Meta(gt=0)]
    temp: float


class HeatConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """`fleet sensor temperature --config heat.yml` (example 21 in snake_case)."""

    drone_id: str | None = None  # or --drone
    rate_ms: Annotated[int, Meta(ge=10, le=60_000)] = 200
    environment_temp: float = 20.0
    heat_sources: list[HeatSource] = []


def temperature_at(environment_temp: float, sources: list[HeatSource], lat: float, lon: float) -> float:
    """Linear fall-off from each source's centre to its radius; the maximum over sources."""
    best = environment_temp
    for src in sources:
        d = distance_m(lat, lon, src.lat, src.lon)
        if d < src.radius:
            best = max(best, src.temp - (src.temp - environment_temp) * d / src.radius)
    return best
