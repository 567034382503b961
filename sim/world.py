"""The world file (SPEC §7): one YAML description of a simulated field, read by
`fleet sim`, `fleet demo` and fast-time simulation alike. Strict: a typo in a key
is an error naming it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import msgspec
from msgspec import Meta

from dronefleet.schemas.about import FieldSpec, Role, SensorDeclaration
from dronefleet.schemas.fence import Geofence
from dronefleet.schemas.geo import destination
from dronefleet.sim.autopilot_params import timing_of
from dronefleet.sim.fault_kinds import FaultKind
from dronefleet.sim.heat_field import HeatConfig, HeatSource, Lat, Lon, temperature_at
from dronefleet.sim.radio import RadioModel, Spot3
from dronefleet.sim.vehicle import Vehicle, VehicleParams
from dronefleet.sim.world_fields import FieldModel, sample

ROW_SPACING_M = 5.0


class _Strict(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


class Spot(_Strict, frozen=True):
    lat: Lat
    lon: Lon
    alt: float = 0.0


class Fault(_Strict, frozen=True):
    at_s: Annotated[float, Meta(ge=0)]
    fault: FaultKind
    value: float | str | None = None


Autopilot = Literal["px4", "ardupilot"]


class DroneSpec(_Strict, frozen=True):
    id: str
    lat: Lat | None = None
    lon: Lon | None = None
    alt: float | None = None
    sensors: list[str | SensorDeclaration] = []  # a type, or a declaration (SPEC §2 About)
    faults: list[Fault] = []
    kind: str | None = None  # its agent's `kind` and `roles` (default: the agent's defaults)
    roles: list[Role] | None = None
    battery: Annotated[float, Meta(ge=0, le=1)] | None = None  # charge at the start (default: full)
    autopilot: Autopilot | None = None  # its simulated flight controller's make (default: px4, or `fleet sim --autopilot`)

    @property
    def sensor_types(self) -> list[str]:
        return [s if isinstance(s, str) else s.type for s in self.sensors]


class FieldSensorSpec(_Strict, frozen=True):
    """A simulated field sensor (not on a drone): it reads the world's `fields` of its type."""

    id: str
    type: str
    lat: Lat
    lon: Lon
    alt: float = 0.0


class BatteryModel(_Strict, frozen=True):
    drain_per_s: Annotated[float, Meta(ge=0)] = 0.0033
    floor: Annotated[float, Meta(ge=0, le=1)] = 0.38


class World(_Strict, frozen=True):
    origin: Spot = Spot(lat=40.633490, lon=-8.660815, alt=8.2)
    ground_station: Spot | None = None
    # Listed drones (none listed: `count` of them in a row); a file listing none is refused.
    drones: Annotated[list[DroneSpec], Meta(min_length=1)] = []
    count: Annotated[int, Meta(ge=1, le=100)] | None = None
    environment_temp: float = 20.0
    heat_sources: list[HeatSource] = []
    fields: dict[str, dict[str, FieldModel]] = {}  # sensor type → field name → model (sim/world_fields.py)
    field_sensors: list[FieldSensorSpec] = []
    field_sensor_rate_ms: Annotated[int, Meta(ge=100, le=600_000)] = 1000
    sensor_rate_ms: Annotated[int, Meta(ge=10, le=60_000)] = 200  # simulated sensors publish this often
    battery: BatteryModel = BatteryModel()
    # Distance → loss between any two nodes (SPEC §8). Fast time flies on a perfect
    # network unless the world has `radio:` (or `simulate --radio`); `fleet sim --radio`
    # always applies it, with the thesis's defaults when absent.
    radio: RadioModel | None = None
    # The field's fence (SPEC §11): fast time gives it to the ground and every agent,
    # as a field would be set up, and paths.png draws it.
    geofence: Geofence | None = None

    @property
    def radio_model(self) -> RadioModel:
        return self.radio or RadioModel()

    def ground_spot3(self) -> Spot3:
        spot = self.ground_spot()
        return Spot3(spot.lat, spot.lon, spot.alt or 0.0)

    def ground_spot(self) -> Spot:
        """Where the field laptop stands: `ground_station`, else the origin, at field level."""
        spot = self.ground_station or self.origin
        return Spot(lat=spot.lat, lon=spot.lon, alt=spot.alt or self.origin.alt)

    def __post_init__(self) -> None:
        missing = sorted({f.type for f in self.field_sensors if f.type not in self.fields and f.type != "temperature"})
        if missing:
            raise ValueError(f"field_sensors of type {', '.join(missing)} need `fields:` of that type to read")

    def declarations(self, spec: DroneSpec) -> list[SensorDeclaration]:
        """What a drone's agent declares of its simulated sensors: as listed, or for a bare
        type the world's fields of that type (temperature: degC)."""
        out = []
        for s in spec.sensors:
            if isinstance(s, SensorDeclaration):
                out.append(s)
            elif s == "temperature":
                out.append(SensorDeclaration(type=s, unit="degC"))
            elif s in self.fields:
                out.append(SensorDeclaration(type=s, fields={name: FieldSpec() for name in self.fields[s]}))
            else:
                out.append(SensorDeclaration(type=s))
        return out

    def reading_at(self, kind: str, lat: float, lon: float) -> dict[str, float | str | bool] | float:
        """What a simulated sensor of `kind` reads there: the world's fields of that type,
        else (temperature) the heat field."""
        if kind in self.fields:
            return sample(self.fields[kind], lat, lon)
        return round(temperature_at(self.environment_temp, self.heat_sources, lat, lon), 3)

    def heat_config(self) -> HeatConfig:
        return HeatConfig(rate_ms=self.sensor_rate_ms, environment_temp=self.environment_temp, heat_sources=self.heat_sources)

    def params(self, autopilot: str | None = None) -> VehicleParams:
        """The vehicle model of a drone: the world's battery, and how its `autopilot`
        make gets going and comes to rest (autopilot_params.TIMING; none: at once)."""
        return VehicleParams(battery_drain_per_s=self.battery.drain_per_s, battery_floor=self.battery.floor,
                             **timing_of(autopilot))

    def vehicle(self, spec: DroneSpec, autopilot: str | None) -> Vehicle:
        """The vehicle model of a spawned drone (`spawn`): where it stands, its battery,
        and how its `autopilot` gets going and comes to rest."""
        assert spec.lat is not None and spec.lon is not None and spec.alt is not None
        vehicle = Vehicle(spec.lat, spec.lon, spec.alt, self.params(autopilot))
        if spec.battery is not None:
            vehicle.battery = spec.battery
        return vehicle

    def spawn(self, n: int | None = None) -> list[DroneSpec]:
        """Drones with positions: the listed ones (first n), or a row east of the origin."""
        if self.drones:
            listed = self.drones[: n or len(self.drones)]
            return [
                msgspec.structs.replace(
                    d, lat=d.lat if d.lat is not None else self.origin.lat,
                    lon=d.lon if d.lon is not None else self.origin.lon,
                    alt=d.alt if d.alt is not None else self.origin.alt,
                )
                for d in listed
            ]
        total = n or self.count or 1
        row = []
        for i in range(total):
            lat, lon = destination(self.origin.lat, self.origin.lon, i * ROW_SPACING_M, 90)
            row.append(DroneSpec(id=f"drone{i + 1:02d}", lat=lat, lon=lon, alt=self.origin.alt))
        return row


def load_world(path: Path | None) -> World:
    """A world file, as strictly as a config file (schemas/config_loading.py); None: the default world."""
    from dronefleet.schemas.config_loading import load_config

    return load_config(World, path, {})
