"""Generic fields of a world (issue 35): any sensor type with named fields, each a
background value plus sources — a gas plume is a source with a centre, a radius and a
peak, falling linearly to the background at the radius (the heat field's shape, for
any quantity). A drone carrying that sensor type, or a field sensor standing in the
field, reads every field where it is.

    fields:
      gas:
        co_ppm: {background: 2, sources: [{lat: 40.6330, lon: -8.6600, radius: 60, peak: 400}]}
        no2_ppb: {background: 10}
"""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta

from dronefleet.sim.heat_field import HeatSource, Lat, Lon, temperature_at


class Source(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    lat: Lat
    lon: Lon
    radius: Annotated[float, Meta(gt=0)]
    peak: float


class FieldModel(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    background: float = 0.0
    sources: list[Source] = []

    def at(self, lat: float, lon: float) -> float:
        """The strongest source's value where it reaches, else the background."""
        return temperature_at(self.background, [HeatSource(lat=s.lat, lon=s.lon, radius=s.radius, temp=s.peak)
                                                for s in self.sources], lat, lon)


def sample(fields: dict[str, FieldModel], lat: float, lon: float) -> dict[str, float]:
    return {name: round(model.at(lat, lon), 3) for name, model in sorted(fields.items())}
