"""Field sensors as a mission sees them (SPEC §5): `field_sensors(type=, near=, within=)`
lists the sensors that are not on a drone, nearest first; `wait(sensor)` waits for its
next reading. Nothing is assigned: any mission may read any field sensor."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from dronefleet.mission.script import units
from dronefleet.mission.script.drone import reading_value
from dronefleet.mission.script.position import Position, as_position
from dronefleet.schemas.telemetry import SensorReading


class FieldSensor:
    """One field sensor's latest reading of one type: `id`, `type`, `position`, `value`
    (a number, or for a sensor with fields an object of them, as `fields`), `timestamp`."""

    __slots__ = ("fields", "id", "position", "timestamp", "type", "value")

    def __init__(self, reading: SensorReading) -> None:
        pos = reading.position
        assert pos is not None  # the ground keeps only field readings that say where they are
        self.id = reading.sensor_id or ""
        self.type = reading.type
        self.position = Position(pos.lat, pos.lon, pos.alt)
        self.value = reading_value(reading)
        self.fields = self.value if reading.fields else None
        self.timestamp = reading.timestamp

    def as_position(self) -> Position:
        return self.position

    def distance(self, other: Any) -> float:
        return self.position.distance(other)

    def __repr__(self) -> str:
        return f"<field sensor {self.id} {self.type} {self.value!r}>"


def field_sensors_of(readings: Sequence[SensorReading], type: str | None = None, near: Any = None,  # noqa: A002 - SPEC's name
                     within: Any = None) -> list[FieldSensor]:
    """The field sensors heard, filtered by type and by distance from `near` (nearest first)."""
    if within is not None and near is None:
        raise TypeError("field_sensors: within= needs near=")
    found = [FieldSensor(r) for r in readings if r.position is not None and (type is None or r.type == type)]
    if near is None:
        return sorted(found, key=lambda s: (s.id, s.type))
    place = as_position(near)
    limit = units.length(within, "within") if within is not None else float("inf")
    nearby = [(s.position.distance(place), s.id, s) for s in found]
    return [s for d, _, s in sorted(nearby, key=lambda t: (t[0], t[1])) if d <= limit]
