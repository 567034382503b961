"""What a drone is (SPEC §2 About) and what its sensors may say (declarations).

An agent's config names its `kind` (free text), its `roles` (⊆ survey, relay,
auxiliary) and its `sensors`: per type either one value (`unit`, `min`, `max`) or
named `fields`, each with a unit and a range. The agent publishes them as About on
`drone/<id>/about`; the ground keeps them and holds every reading to them
(`reading_fault`): a reading outside its declaration is logged and dropped, never
shown as a value (thesis §7.2 item 2: sensor types in configuration, not in code).
"""

from __future__ import annotations

import math
import re
from typing import Literal, get_args

import msgspec

from dronefleet.schemas.telemetry import SensorReading

Role = Literal["survey", "relay", "auxiliary"]
ROLES: tuple[str, ...] = get_args(Role)
DEFAULT_KIND = "multicopter"
DEFAULT_ROLES: tuple[Role, ...] = ("survey",)
AUXILIARY = "auxiliary"
RELAY = "relay"
_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")  # a key chunk (sensor type) or a Python name part (field)


class _Strict(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True, omit_defaults=True):
    pass


class FieldSpec(_Strict, frozen=True):
    """One value a sensor reports: its unit and the range a real reading stays in. One
    declared with neither is any value: a number, a word (`status: "ok"`) or a flag."""

    unit: str = ""
    min: float | None = None
    max: float | None = None

    def __post_init__(self) -> None:
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"min {self.min:g} is above max {self.max:g}")


class SensorDeclaration(_Strict, frozen=True):
    """A sensor type a drone carries: one value (`unit`, `min`, `max`), or `fields`."""

    type: str
    unit: str = ""
    min: float | None = None
    max: float | None = None
    fields: dict[str, FieldSpec] = {}

    def __post_init__(self) -> None:
        if not _NAME.match(self.type):
            raise ValueError(f"sensor type {self.type!r}: use letters, digits, '_' or '-'")
        bad = [name for name in self.fields if not name.isidentifier() or name.startswith("_")]
        if bad:
            raise ValueError(f"sensor {self.type}: field names must be identifiers not starting with '_' "
                             f"(missions read drone.sensor.{self.type}.<field>), got {', '.join(map(repr, bad))}")
        if self.fields and (self.unit or self.min is not None or self.max is not None):
            raise ValueError(f"sensor {self.type}: give unit/min/max per field when it has fields")
        FieldSpec(unit=self.unit, min=self.min, max=self.max)  # the same range check


class About(msgspec.Struct, frozen=True, kw_only=True):
    drone_id: str
    timestamp: int
    kind: str = DEFAULT_KIND
    roles: list[Role] = msgspec.field(default_factory=lambda: list(DEFAULT_ROLES))
    sensors: list[SensorDeclaration] = msgspec.field(default_factory=list)
    # The flight controller's make as the agent found it: px4 or ardupilot (None: the
    # built-in simulator, or an agent that does not say). Predictions fly each drone
    # with its make's timing (ground/planning.py).
    autopilot: str | None = None

    def same_as(self, other: About | None) -> bool:
        """The same description (the timestamp aside)."""
        return other is not None and ((self.kind, self.roles, self.sensors, self.autopilot)
                                      == (other.kind, other.roles, other.sensors, other.autopilot))


def _number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _range_fault(label: str, value: object, spec: FieldSpec) -> str | None:
    if spec.min is None and spec.max is None and not spec.unit:
        return None  # declared without a unit or range: any value
    if not _number(value):
        return f"{label} is {value!r}, not a number"
    assert isinstance(value, (int, float))
    if spec.min is not None and value < spec.min or spec.max is not None and value > spec.max:
        return f"{label} {value:g} is outside [{_bound(spec.min)}, {_bound(spec.max)}]"
    return None


def _bound(value: float | None) -> str:
    return "…" if value is None else f"{value:g}"


def reading_fault(reading: SensorReading, declared: list[SensorDeclaration]) -> str | None:
    """Why `reading` is outside the drone's (or field sensor's) declarations, or None.
    Nothing declared at all: nothing to hold it to."""
    if not declared:
        return None
    decl = next((d for d in declared if d.type == reading.type), None)
    if decl is None:
        return f"undeclared sensor type {reading.type!r} (declared: {', '.join(d.type for d in declared)})"
    if not decl.fields:
        if reading.fields:
            return f"{reading.type} is declared with one value, the reading has fields {', '.join(sorted(reading.fields))}"
        return _range_fault(f"{reading.type} value", reading.value,
                            FieldSpec(unit=decl.unit, min=decl.min, max=decl.max))
    if not reading.fields:
        return f"{reading.type} is declared with fields {', '.join(sorted(decl.fields))}; the reading has none"
    for name, value in reading.fields.items():
        spec = decl.fields.get(name)
        if spec is None:
            return f"unknown field {reading.type}.{name} (declared: {', '.join(sorted(decl.fields))})"
        if value is None:  # not read this time, as a field it did not carry
            continue
        fault = _range_fault(f"{reading.type}.{name}", value, spec)
        if fault is not None:
            return fault
    return None


def sensor_types(declared: list[SensorDeclaration]) -> list[str]:
    return sorted(d.type for d in declared)


def may_relay(relays: frozenset[str] | None, drone_id: str, roles: list[str] | None) -> bool:
    """Whether a drone may be sent as a relay. On an open mesh (`relays` None: no access
    rules) any drone may. On a secured mesh (SPEC §9) it needs both: a certificate
    issued `--role relay` (else the routers drop what it forwards) and the `relay` role
    in its About (the operator's word that it may leave its own work) — until its About
    is heard, the certificate alone."""
    if relays is None:
        return True
    return drone_id in relays and (roles is None or RELAY in roles)


def relay_disagreement(relays: frozenset[str] | None, drone_id: str, roles: list[str]) -> str | None:
    """On a secured mesh, how a drone's certificate and its declared roles disagree on
    relaying (it is then not sent as a relay), or None."""
    if relays is None:
        return None
    if drone_id in relays and RELAY not in roles:
        return ("its certificate lets it relay, but its About does not declare the relay role: "
                "it is not sent as a relay (add `relay` to the agent's roles)")
    if drone_id not in relays and RELAY in roles:
        return ("it declares the relay role, but its certificate was not issued --role relay, so the routers "
                "would drop what it forwards: it is not sent as a relay (issue it `fleet pki issue … --role relay`)")
    return None
