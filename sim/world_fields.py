"""Generic fields of a world (issue 35): any sensor type with named fields, each a
background value plus sources — a gas plume is a source with a centre, a radius and a
peak, falling linearly to the background at the radius (the heat field's shape, for
any quantity). A drone carrying that sensor type, or a field sensor standing in the
field, reads every field where it is.

    fields:
      gas:
        co_ppm: {background: 2, sources: [{lat: 40.6330, lon: -8.6600, radius: 60, peak: 400}]}
        no2_ppb: {background: 10}
        status: {background: ok}     # a word (or a flag) is read as it is, everywhere
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
    # A number, or a word or flag the sensor reports as it is (`status: {background: ok}`)
    background: float | str | bool = 0.0
    sources: list[Source] = []

    def __post_init__(self) -> None:
        if self.sources and not _number(self.background):
            raise ValueError(f"a field with sources has a numeric background, not {self.background!r}")

    def at(self, lat: float, lon: float) -> float | str | bool:
        """The strongest source's value where it reaches, else the background."""
        if not _number(self.background):
            return self.background
        return round(temperature_at(float(self.background), [HeatSource(lat=s.lat, lon=s.lon, radius=s.radius, temp=s.peak)
                                                             for s in self.sources], lat, lon), 3)


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def sample(fields: dict[str, FieldModel], lat: float, lon: float) -> dict[str, float | str | bool]:
    return {name: model.at(lat, lon) for name, model in sorted(fields.items())}
