"""Field sensors: sensors that are not on a drone (SPEC §2 `sensor/<id>/<type>`).

A gas sensor on a pole, a weather station, a Raspberry Pi beside a real sensor: each
publishes SensorReadings with its `sensor_id` and `position` and declares itself with a
liveliness token `sensor/<id>/alive`. The ground keeps the latest reading per (sensor,
type); a type falls silent past `sensor_timeout_ms[type]` (0 = never) like a drone's
sensor, and a sensor with no reading left is forgotten. Its token going is logged (it
may have been a one-shot `fleet sensor publish`); its readings stay until they time out.

Pure logic, as the drone registry: events in, log lines out (ground/registry.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec

from dronefleet.ground.describe import Level
from dronefleet.schemas.telemetry import Position, SensorReading


class FieldSensorInfo(msgspec.Struct, frozen=True, kw_only=True):
    """`GET /sensor` and `GET /sensor/{id}`: one field sensor as the ground knows it."""

    sensor_id: str
    position: Position | None
    alive: bool | None  # its liveliness token: None until seen either way
    types: list[str]
    last_heard: int  # ms since the epoch (ground clock)
    readings: list[SensorReading]


@dataclass
class _Field:
    sensor_id: str
    position: Position | None = None
    alive: bool | None = None
    readings: dict[str, tuple[SensorReading, int]] = field(default_factory=dict)  # type → (reading, heard at ms)

    def info(self) -> FieldSensorInfo:
        heard = max((at for _, at in self.readings.values()), default=0)
        return FieldSensorInfo(sensor_id=self.sensor_id, position=self.position, alive=self.alive,
                               types=sorted(self.readings), last_heard=heard,
                               readings=[self.readings[t][0] for t in sorted(self.readings)])


class FieldSensors:
    def __init__(self, timeouts_ms: dict[str, int]) -> None:
        self.timeouts_ms = timeouts_ms
        self._sensors: dict[str, _Field] = {}

    def ids(self) -> list[str]:
        return sorted(self._sensors)

    def get(self, sensor_id: str) -> FieldSensorInfo | None:
        sensor = self._sensors.get(sensor_id)
        return sensor.info() if sensor is not None else None

    def readings(self) -> list[SensorReading]:
        """The latest reading of every (field sensor, type), as missions read them."""
        return [s.readings[t][0] for s in self._sensors.values() for t in sorted(s.readings)]

    def on_reading(self, reading: SensorReading, now_ms: int) -> tuple[list[tuple[Level, str]], SensorReading | None]:
        """Log lines (level, sensor id, message) and the reading as kept (with the
        sensor's position when it did not repeat it), or None when it is dropped."""
        sensor_id = reading.sensor_id or ""
        sensor = self._sensors.get(sensor_id)
        position = reading.position or (sensor.position if sensor is not None else None)
        if position is None:
            return [("warn", f"Dropped a {reading.type} reading of field sensor {sensor_id}: "
                             "no position (a field sensor's first reading says where it stands)")], None
        lines: list[tuple[Level, str]] = []
        if sensor is None:
            sensor = self._sensors[sensor_id] = _Field(sensor_id)
            lines.append(("info", f"Field sensor {sensor_id} registered at {position.lat:.6f}, {position.lon:.6f}"))
        if reading.type not in sensor.readings:
            lines.append(("info", f"Field sensor {sensor_id}: detected {reading.type}"))
        sensor.position = position
        kept = msgspec.structs.replace(reading, position=position, drone_id="")
        sensor.readings[reading.type] = (kept, now_ms)
        return lines, kept

    def on_liveliness(self, sensor_id: str, alive: bool) -> list[tuple[Level, str]]:
        sensor = self._sensors.get(sensor_id)
        if sensor is None:
            if alive:  # its first reading registers it; the token says it is there
                self._sensors[sensor_id] = _Field(sensor_id, alive=True)
            return []
        was, sensor.alive = sensor.alive, alive
        if was is not False and not alive:
            return [("warn", f"Field sensor {sensor_id}: liveliness token lost (its readings stay until they time out)")]
        if was is False and alive:
            return [("info", f"Field sensor {sensor_id}: back")]
        return []

    def tick(self, now_ms: int) -> tuple[list[tuple[Level, str]], list[tuple[str, str]]]:
        """Timeouts: log lines and the (sensor id, type) pairs that went."""
        lines: list[tuple[Level, str]] = []
        gone: list[tuple[str, str]] = []
        for sensor_id, sensor in list(self._sensors.items()):
            for kind, (_, heard) in list(sensor.readings.items()):
                limit = self.timeouts_ms.get(kind, 0)
                if limit and now_ms - heard > limit:
                    del sensor.readings[kind]
                    gone.append((sensor_id, kind))
                    lines.append(("warn", f"Field sensor {sensor_id}: lost {kind}, no reading for {limit} ms"))
            if not sensor.readings and sensor.alive is not True and (sensor.position is not None or sensor.alive is False):
                del self._sensors[sensor_id]
                lines.append(("warn", f"Field sensor {sensor_id} forgotten: no reading left and no liveliness token"))
        return lines, gone
