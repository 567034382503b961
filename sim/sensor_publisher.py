"""Field sensors (SPEC §2): sensors that are not on a drone publish `sensor/<id>/<type>`
with their position and declare themselves with a liveliness token `sensor/<id>/alive`.

`fleet sensor publish` sends one reading (or one per JSON line on stdin: a script on a
Raspberry Pi beside a real sensor); world files place simulated field sensors, which
read the world's fields (sim/world_fields.py) where they stand.
"""

from __future__ import annotations

import asyncio
import json
import logging
import sys
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Any

from dronefleet.bus.clock import Clock, SystemClock
from dronefleet.bus.port import Bus
from dronefleet.schemas.codec import encode
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.keys import Keys, check_id
from dronefleet.schemas.telemetry import Position, SensorReading

if TYPE_CHECKING:
    from dronefleet.sim.world import FieldSensorSpec, World

log = logging.getLogger(__name__)


def parse_at(text: str) -> Position:
    """`LAT,LON[,ALT]` (degrees, metres AMSL)."""
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not (-90 <= values[0] <= 90 and -180 <= values[1] <= 180):
        raise InvalidMessage(f"--at {text!r}: give LAT,LON or LAT,LON,ALT in degrees (and metres)", field="at")
    return Position(lat=values[0], lon=values[1], alt=values[2] if len(values) == 3 else 0.0)


def parse_fields(pairs: tuple[str, ...] | list[str]) -> dict[str, float]:
    """`co_ppm=12.5 no2_ppb=31` → {"co_ppm": 12.5, "no2_ppb": 31.0}."""
    fields: dict[str, float] = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name.isidentifier():
            raise InvalidMessage(f"{pair!r}: give FIELD=NUMBER, e.g. co_ppm=12.5", field=name or pair)
        try:
            fields[name] = float(value)
        except ValueError:
            raise InvalidMessage(f"{pair!r}: {value!r} is not a number", field=name) from None
    return fields


def reading_of(sensor_id: str, sensor_type: str, at: Position, timestamp: int, *, value: Any = None,
               fields: dict[str, Any] | None = None, unit: str = "") -> SensorReading:
    return SensorReading(drone_id="", sensor_id=check_id(sensor_id, "sensor id"), timestamp=timestamp,
                         type=check_id(sensor_type, "sensor type"), value=value, fields=fields or None, unit=unit,
                         position=at)


def reading_from_line(line: str, sensor_id: str, sensor_type: str, at: Position, timestamp: int) -> SensorReading:
    """One JSON line of stdin: `{"co_ppm": 12.5}` (fields), `{"fields": {…}}`, `{"value": 21.5,
    "unit": "degC"}`; `"at": [lat, lon, alt]` moves the sensor."""
    try:
        obj = json.loads(line)
    except ValueError as exc:
        raise InvalidMessage(f"not a JSON line: {exc}") from None
    if not isinstance(obj, dict):
        raise InvalidMessage("a JSON object per line, e.g. {\"co_ppm\": 12.5}")
    if "at" in obj:
        at = parse_at(",".join(str(v) for v in obj.pop("at")))
    unit = str(obj.pop("unit", ""))
    if "value" in obj:
        return reading_of(sensor_id, sensor_type, at, timestamp, value=obj.pop("value"), unit=unit)
    fields = obj.pop("fields", None) if "fields" in obj else obj
    if not isinstance(fields, dict) or not fields:
        raise InvalidMessage("no value and no fields in the line")
    return reading_of(sensor_id, sensor_type, at, timestamp, fields=fields, unit=unit)


async def publish_readings(bus: Bus, sensor_id: str, readings: AsyncIterator[SensorReading],
                           out: Callable[[str], None], keys: Keys | None = None) -> int:
    """Announce the sensor (liveliness) and publish each reading; returns how many."""
    keys = keys or Keys()
    token = bus.announce(keys.field_sensor_alive(sensor_id))
    sent = 0
    try:
        async for reading in readings:
            bus.publish(keys.field_sensor(sensor_id, reading.type), encode(reading), reliable=True)
            sent += 1
            shown = reading.data
            out(f"{sensor_id} {reading.type} {shown} at {reading.position.lat:.6f}, {reading.position.lon:.6f}"
                if reading.position else f"{sensor_id} {reading.type} {shown}")
    finally:
        token.close()
    return sent


async def world_field_sensor(bus: Bus, world: World, spec: FieldSensorSpec, clock: Clock | None = None,
                             keys: Keys | None = None, out: Callable[[str], None] | None = None) -> None:
    """A field sensor the world file places: the world's fields of its type where it stands."""
    await simulated_field_sensor(bus, spec.id, spec.type, Position(lat=spec.lat, lon=spec.lon, alt=spec.alt),
                                 lambda where: world.reading_at(spec.type, where.lat, where.lon),
                                 world.field_sensor_rate_ms, clock, keys, out)


async def simulated_field_sensor(bus: Bus, sensor_id: str, sensor_type: str, at: Position,
                                 sample: Callable[[Position], dict[str, float | str | bool] | float], rate_ms: int,
                                 clock: Clock | None = None, keys: Keys | None = None,
                                 out: Callable[[str], None] | None = None) -> None:
    """A world's field sensor: the world's field where it stands, every `rate_ms`; `out` gets a line per reading."""
    clock = clock or SystemClock()

    async def readings() -> AsyncIterator[SensorReading]:
        while True:
            measured = sample(at)
            if isinstance(measured, dict):
                yield reading_of(sensor_id, sensor_type, at, clock.time_ms(), fields=measured)
            else:
                yield reading_of(sensor_id, sensor_type, at, clock.time_ms(), value=measured)
            await clock.sleep(rate_ms / 1000)

    await publish_readings(bus, sensor_id, readings(), out or (lambda line: None), keys)


async def run_publish(sensor_id: str, sensor_type: str, at: Position, value: float | None, fields: dict[str, float],
                      unit: str, connect: list[str], extra: dict[str, Any], out: Callable[[str], None]) -> int:
    """`fleet sensor publish`: one reading from the command line, or one per stdin line."""
    from dronefleet.bus.zenoh_bus import ZenohBus

    clock = SystemClock()
    check_id(sensor_id, "sensor id")
    check_id(sensor_type, "sensor type")

    async def readings() -> AsyncIterator[SensorReading]:
        if value is not None or fields:
            yield reading_of(sensor_id, sensor_type, at, clock.time_ms(), value=value, fields=fields, unit=unit)
            return
        loop = asyncio.get_running_loop()
        number = 0
        while line := await loop.run_in_executor(None, sys.stdin.readline):
            number += 1
            if not line.strip():
                continue
            try:
                yield reading_from_line(line, sensor_id, sensor_type, at, clock.time_ms())
            except InvalidMessage as exc:  # one bad line is skipped, the sensor goes on
                print(f"fleet sensor publish: stdin line {number} skipped: {exc}", file=sys.stderr)

    bus = await ZenohBus.open("client", connect=connect, wait=True, extra=extra)
    try:
        return await publish_readings(bus, sensor_id, readings(), out)
    finally:
        await bus.close()
