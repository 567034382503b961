"""Simulated sensors: the temperature sensor of thesis example 21, and any sensor type
the world gives `fields` (sim/world_fields.py: a gas plume, say), read the same way.

A heat field is an environment temperature plus heat sources, each a centre, a
radius and a centre temperature: inside a source the temperature falls linearly from
the centre's to the environment's at the radius; with several sources the hottest
wins. The sensor follows a drone's live telemetry (`drone/<id>/telem`) and publishes
the temperature where the drone is on `drone/<id>/sensor/temperature` every `rate_ms`.

The same code runs as `fleet sensor temperature --drone ID --config heat.yml` next to
a real or simulated drone, as `fleet sensor simulate --world W --drone ID --type T`
(any type the world's `fields:` give, or a world's field sensor with `--field ID`),
and inside `fleet demo` and fast-time simulation, where the field comes from the
world file (SPEC §7).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Coroutine, Sequence
from typing import TYPE_CHECKING, Any

from dronefleet.bus.clock import Clock, SystemClock
from dronefleet.bus.port import Bus, Sample
from dronefleet.schemas.codec import decode_telemetry, encode
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import SensorReading, Telemetry
from dronefleet.sim.heat_field import HeatConfig, temperature_at
from dronefleet.sim.world_fields import sample

if TYPE_CHECKING:
    from dronefleet.sim.world import World

log = logging.getLogger(__name__)


class TemperatureSensor:
    """Publishes the heat field's temperature where the drone's telemetry says it is."""

    def __init__(self, bus: Bus, drone_id: str, config: HeatConfig, *, clock: Clock | None = None,
                 keys: Keys | None = None, on_reading: Callable[[SensorReading], None] | None = None,
                 kind: str = "temperature", model: Callable[[float, float], dict[str, float | str | bool]] | None = None) -> None:
        """`model`: another type's fields where the drone is (sim/world_fields.py), instead of the heat field."""
        self.kind = kind
        self.model = model
        self.bus = bus
        self.drone_id = drone_id
        self.config = config
        self.clock = clock or SystemClock()
        self.keys = keys or Keys()
        self.on_reading = on_reading
        self.telemetry: Telemetry | None = None
        self.published = 0
        self.has_telemetry = asyncio.Event()

    def _on_telem(self, sample: Sample) -> None:
        try:
            self.telemetry = decode_telemetry(sample.payload)
        except Exception as exc:  # noqa: BLE001 - a bad sample is skipped, the sensor goes on
            log.warning("%s: undecodable telemetry skipped: %s", self.drone_id, exc)
            return
        self.has_telemetry.set()

    def reading(self) -> SensorReading | None:
        t = self.telemetry
        if t is None or t.position is None:
            return None
        if self.model is not None:
            return SensorReading(drone_id=self.drone_id, timestamp=self.clock.time_ms(), type=self.kind,
                                 fields=dict(self.model(t.position.lat, t.position.lon)))
        value = temperature_at(self.config.environment_temp, self.config.heat_sources, t.position.lat, t.position.lon)
        return SensorReading(drone_id=self.drone_id, timestamp=self.clock.time_ms(), type="temperature",
                             value=round(value, 3), unit="degC")

    async def run(self) -> None:
        sub = self.bus.subscribe(self.keys.telem(self.drone_id), self._on_telem, latest_only=True)
        key = self.keys.sensor(self.drone_id, self.kind)
        try:
            while True:
                reading = self.reading()
                if reading is not None:
                    self.bus.publish(key, encode(reading))
                    self.published += 1
                    if self.on_reading is not None:
                        self.on_reading(reading)
                await self.clock.sleep(self.config.rate_ms / 1000)
        finally:
            sub.close()


def simulated_sensor(bus: Bus, drone_id: str, kind: str, world: World, *, clock: Clock | None = None,
                     keys: Keys | None = None, on_reading: Callable[[SensorReading], None] | None = None,
                     fields: Sequence[str] = ()) -> Coroutine[Any, Any, None]:
    """The world's simulated sensor `kind` on a drone: temperature from the heat field;
    any other kind is announced with readings of value None (or, declared with `fields`,
    each field None), so missions can assign by it and read that nothing is known."""
    if kind == "temperature":
        return TemperatureSensor(bus, drone_id, world.heat_config(), clock=clock, keys=keys, on_reading=on_reading).run()
    if kind in world.fields:  # a sensor with fields (sim/world_fields.py): each read where the drone is
        return TemperatureSensor(bus, drone_id, world.heat_config(), clock=clock, keys=keys, kind=kind, on_reading=on_reading,
                                 model=lambda lat, lon: sample(world.fields[kind], lat, lon)).run()
    return _announce(bus, drone_id, kind, world.sensor_rate_ms, clock or SystemClock(), keys or Keys(), on_reading, fields)


async def _announce(bus: Bus, drone_id: str, kind: str, rate_ms: int, clock: Clock, keys: Keys,
                    on_reading: Callable[[SensorReading], None] | None, fields: Sequence[str]) -> None:
    while True:
        reading = SensorReading(drone_id=drone_id, timestamp=clock.time_ms(), type=kind, value=None,
                                fields=dict.fromkeys(fields) or None)
        bus.publish(keys.sensor(drone_id, kind), encode(reading))
        if on_reading is not None:
            on_reading(reading)
        await clock.sleep(rate_ms / 1000)


def reading_line(reading: SensorReading) -> str:
    """What `fleet sensor` prints of a drone's reading: `drone01 temperature 42.00 °C`, `drone02 gas co_ppm=61.2`."""
    if reading.fields:
        shown = " ".join(f"{name}={value:g}" if isinstance(value, (int, float)) else f"{name}={value}"
                         for name, value in reading.fields.items())
    elif reading.type == "temperature" and isinstance(reading.value, (int, float)):
        shown = f"{reading.value:.2f} °C"
    else:
        shown = f"{reading.value} {reading.unit}".rstrip()
    return f"{reading.drone_id} {reading.type} {shown}"


SensorProgram = Callable[[Bus, Callable[[str], None]], Coroutine[Any, Any, None]]


async def run_sensor_program(program: SensorProgram, connect: list[str], out: Callable[[str], None],
                             count: int | None = None, extra: dict[str, Any] | None = None) -> None:
    """A `fleet sensor` program as a Zenoh client next to a drone's agent (or the ground):
    `program(bus, show)` publishes and calls `show` with a line per reading; with `count`,
    the program ends after that many."""
    from dronefleet.bus.zenoh_bus import ZenohBus

    bus = await ZenohBus.open("client", connect=connect, wait=True, extra=extra)  # the agent may start later
    done = asyncio.Event()
    shown = 0

    def show(line: str) -> None:
        nonlocal shown
        out(line)
        shown += 1
        if count is not None and shown >= count:
            done.set()

    task = asyncio.get_running_loop().create_task(program(bus, show), name="sensor")
    try:
        await asyncio.wait([task, asyncio.ensure_future(done.wait())], return_when=asyncio.FIRST_COMPLETED)
        if task.done():
            task.result()
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await bus.close()


async def run_temperature_sensor(drone_id: str, config: HeatConfig, connect: list[str],
                                 out: Callable[[str], None], count: int | None = None,
                                 extra: dict[str, Any] | None = None) -> None:
    """`fleet sensor temperature`: the heat field of `config` where the drone is."""
    out(f"fleet sensor: temperature of {drone_id} every {config.rate_ms} ms, "
        f"{len(config.heat_sources)} heat source(s), {config.environment_temp:g} °C around; waiting for its telemetry")

    def program(bus: Bus, show: Callable[[str], None]) -> Coroutine[Any, Any, None]:
        return TemperatureSensor(bus, drone_id, config, on_reading=lambda r: show(reading_line(r))).run()

    await run_sensor_program(program, connect, out, count, extra)


def world_sensor_program(world: World, *, drone_id: str | None = None, kind: str | None = None,
                         field_id: str | None = None) -> tuple[SensorProgram, str]:
    """`fleet sensor simulate`: a drone's sensor `kind` read from the world where the drone's
    telemetry puts it, or the world's field sensor `field_id` where it stands; with a line
    saying what runs. A type the world cannot read is a ConfigError naming what it has."""
    from dronefleet.sim.sensor_publisher import world_field_sensor

    readable = sorted({"temperature", *world.fields})
    if field_id is not None:
        spec = next((f for f in world.field_sensors if f.id == field_id), None)
        if spec is None:
            have = ", ".join(f.id for f in world.field_sensors) or "none"
            raise ConfigError(f"--field {field_id}: the world places no such field sensor (it has: {have})")
        if kind is not None and kind != spec.type:
            raise ConfigError(f"--type {kind}: field sensor {field_id} measures {spec.type}")
        about = (f"fleet sensor: field sensor {spec.id} ({spec.type}) at {spec.lat:.6f}, {spec.lon:.6f} "
                 f"every {world.field_sensor_rate_ms} ms")
        return (lambda bus, show: world_field_sensor(bus, world, spec, out=show)), about
    carried = {d.id: d.sensor_types for d in world.drones}
    if drone_id is None or kind is None:
        hint = f" ({drone_id} carries {', '.join(carried[drone_id])} in the world)" if drone_id and carried.get(drone_id) else ""
        raise ConfigError(f"give --drone ID --type TYPE (a sensor on a drone) or --field ID (a field sensor of the world){hint}")
    if kind in readable:
        source = "heat field" if kind == "temperature" else "fields " + ", ".join(world.fields[kind])
        about = f"fleet sensor: {kind} of {drone_id} every {world.sensor_rate_ms} ms from the world's {source}; waiting for its telemetry"
    elif kind in carried.get(drone_id, ()):  # as fast time does: there, without values, for missions to assign by
        about = f"fleet sensor: {kind} of {drone_id} announced without values (the world has no `fields:` of that type)"
    else:
        raise ConfigError(f"--type {kind}: the world has no `fields:` of that type to read (it reads: {', '.join(readable)})")
    return (lambda bus, show: simulated_sensor(bus, drone_id, kind, world, on_reading=lambda r: show(reading_line(r)))), about
