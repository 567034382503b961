"""Simulated sensors: the temperature sensor of thesis example 21, and any sensor type
the world gives `fields` (sim/field_model.py: a gas plume, say), read the same way.

A heat field is an environment temperature plus heat sources, each a centre, a
radius and a centre temperature: inside a source the temperature falls linearly from
the centre's to the environment's at the radius; with several sources the hottest
wins. The sensor follows a drone's live telemetry (`drone/<id>/telem`) and publishes
the temperature where the drone is on `drone/<id>/sensor/temperature` every `rate_ms`.

The same code runs as `fleet sensor temperature --drone ID --config heat.yml` next to
a real or simulated drone, and inside `fleet demo` and fast-time simulation, where the
field comes from the world file (SPEC §7).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Coroutine
from typing import TYPE_CHECKING, Any

from dronefleet.bus.clock import Clock, SystemClock
from dronefleet.bus.port import Bus, Sample
from dronefleet.schemas.codec import decode_telemetry, encode
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import SensorReading, Telemetry
from dronefleet.sim.field_model import sample
from dronefleet.sim.heat_field import HeatConfig, temperature_at

if TYPE_CHECKING:
    from dronefleet.sim.world import World

log = logging.getLogger(__name__)


class TemperatureSensor:
    """Publishes the heat field's temperature where the drone's telemetry says it is."""

    def __init__(self, bus: Bus, drone_id: str, config: HeatConfig, *, clock: Clock | None = None,
                 keys: Keys | None = None, on_reading: Callable[[SensorReading], None] | None = None,
                 kind: str = "temperature", model: Callable[[float, float], dict[str, float]] | None = None) -> None:
        """`model`: another type's fields where the drone is (sim/field_model.py), instead of the heat field."""
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
                     keys: Keys | None = None) -> Coroutine[Any, Any, None]:
    """The world's simulated sensor `kind` on a drone: temperature from the heat field;
    any other kind is announced with readings of value None, so missions can assign by it."""
    if kind == "temperature":
        return TemperatureSensor(bus, drone_id, world.heat_config(), clock=clock, keys=keys).run()
    if kind in world.fields:  # a sensor with fields (sim/field_model.py): each read where the drone is
        return TemperatureSensor(bus, drone_id, world.heat_config(), clock=clock, keys=keys, kind=kind,
                                 model=lambda lat, lon: sample(world.fields[kind], lat, lon)).run()
    return _announce(bus, drone_id, kind, world.sensor_rate_ms, clock or SystemClock(), keys or Keys())


async def _announce(bus: Bus, drone_id: str, kind: str, rate_ms: int, clock: Clock, keys: Keys) -> None:
    while True:
        reading = SensorReading(drone_id=drone_id, timestamp=clock.time_ms(), type=kind, value=None)
        bus.publish(keys.sensor(drone_id, kind), encode(reading))
        await clock.sleep(rate_ms / 1000)


async def run_temperature_sensor(drone_id: str, config: HeatConfig, connect: list[str],
                                 out: Callable[[str], None], count: int | None = None,
                                 extra: dict[str, Any] | None = None) -> None:
    """`fleet sensor temperature`: a Zenoh client next to the drone's agent."""
    from dronefleet.bus.zenoh_bus import ZenohBus

    bus = await ZenohBus.open("client", connect=connect, wait=True, extra=extra)  # the agent may start later
    done = asyncio.Event()

    def show(reading: SensorReading) -> None:
        out(f"{reading.drone_id} temperature {reading.value:.2f} °C")
        if count is not None and sensor.published >= count:
            done.set()

    sensor = TemperatureSensor(bus, drone_id, config, on_reading=show)
    out(f"fleet sensor: temperature of {drone_id} every {config.rate_ms} ms, "
        f"{len(config.heat_sources)} heat source(s), {config.environment_temp:g} °C around; waiting for its telemetry")
    task = asyncio.get_running_loop().create_task(sensor.run(), name="temperature sensor")
    try:
        await asyncio.wait([task, asyncio.ensure_future(done.wait())], return_when=asyncio.FIRST_COMPLETED)
        if task.done():
            task.result()
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await bus.close()
