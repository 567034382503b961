"""Task bundles (SPEC §6): steps a drone runs on its own, guards as data, their record.

Wire shape — a query on `drone/<id>/bundle` with a TaskBundle; the reply is a
BundleReply. Steps are Commands of SPEC §2 (without drone_id/timestamp/command_id) or
`{"wait_s": N}`, each with an optional `until` guard; the bundle has its own `until`,
`on_link_loss` and `timeout_s`. A guard is `{"field", "op", "value"}` on a dotted
Telemetry path or `sensor.<type>`, or `{"all": […]}` / `{"any": […]}` — data the agent
compares, never code it runs.

`parse_bundle` validates the whole bundle before anything runs and names the step and
field at fault (`step 4: lat: Expected float >= -90`, field `$.steps[4].lat`). Step
numbers on the wire are indexes into `steps` (0-based, as in the JSON path); log lines
for people say "step 5/8".
"""

from __future__ import annotations

import json
import math
import operator
import typing
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from dronefleet.schemas.auth import Auth
from dronefleet.schemas.commands import COMMAND_TYPES, Command, decode_command
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.telemetry import Telemetry

LinkLossPolicy = Literal["continue", "hold", "return"]
BundleState = Literal["running", "done", "ended", "failed", "cancelled"]
# Progress on drone/<id>/status: a step starts, finishes or is ended by its guard; the
# bundle is done, ended (by its guard, its link-loss policy), failed or cancelled.
BundleEvent = Literal["start", "finish", "guard", "done", "failure", "cancel"]  # SPEC §6
BUNDLE_ENDS: dict[str, BundleState] = {"done": "done", "guard": "ended", "failure": "failed", "cancel": "cancelled"}
MAX_STEPS = 1000
OPS: dict[str, Callable[[Any, Any], bool]] = {
    "<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge, "==": operator.eq, "!=": operator.ne,
}
STEP_FIELDS = frozenset({"until"})
NOT_IN_STEPS = ("drone_id", "timestamp", "command_id", "auth")


def new_bundle_id() -> str:
    """A fresh bundle id, short enough to read in log lines: `b-3f9c2a7e1b04`."""
    return f"b-{uuid.uuid4().hex[:12]}"


class TaskBundle(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The wire form. `steps` and `until` stay JSON here; `parse_bundle` checks them."""

    drone_id: str = ""
    timestamp: int = 0
    bundle_id: str
    steps: list[dict[str, Any]]
    on_link_loss: LinkLossPolicy = "continue"
    timeout_s: Annotated[float, Meta(gt=0, le=86_400)] | None = None
    until: dict[str, Any] | None = None
    auth: Auth | None = None  # the ground's signature (SPEC §9)
    ground_epoch: Annotated[int, Meta(ge=0)] = 0  # SPEC §14: the sending ground's epoch (0: none)
    ground_id: str = ""  # the sending ground: an epoch is held by the first ground an agent heard with it


class BundleReply(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    bundle_id: str
    accepted: bool
    reason: str | None = None
    ground_epoch: int | None = None  # with `stale_ground`: the newest ground epoch the agent heard (SPEC §14)


class BundleStatus(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """Progress of a bundle on `drone/<id>/status` (told apart by `bundle_id`)."""

    drone_id: str
    timestamp: int
    bundle_id: str
    step: int  # index into steps; for the bundle's own end, the step it was at
    state: BundleEvent
    reason: str | None = None  # guard: which guard (or "link lost (on_link_loss=…)"); failure/cancel: why
    scope: Literal["bundle"] | None = None  # a guard that ended the whole bundle, not just its step
    steps: int | None = None  # how many steps the bundle has
    command: str | None = None  # the step's cmd, or "wait"

    @property
    def ends_bundle(self) -> bool:
        return self.scope == "bundle" if self.state == "guard" else self.state in BUNDLE_ENDS


class StepEvent(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    step: int
    state: BundleEvent
    timestamp: int  # ms since the epoch (the drone's clock)
    reason: str | None = None
    scope: Literal["bundle"] | None = None


class BundleRecord(msgspec.Struct, kw_only=True):
    """What the agent keeps of a bundle and answers `drone/<id>/bundle?id=…` with (every
    field, also a 0 or null: SPEC §6 lists them)."""

    bundle_id: str
    state: BundleState
    step: int = 0  # the current (or last) step's index
    steps: int = 0
    steps_done: int = 0
    ended_by: str | None = None  # the guard (or policy) that ended it
    reason: str | None = None  # failed / cancelled: why
    started: int = 0  # ms since the epoch
    ended: int | None = None
    history: list[StepEvent] = msgspec.field(default_factory=list)  # every event, as published

    @property
    def finished(self) -> bool:
        return self.state != "running"


# ---- guards ----------------------------------------------------------------------


@dataclass(frozen=True)
class Compare:
    field: str
    op: str
    value: Any

    def holds(self, values: Callable[[str], Any]) -> bool:
        current = values(self.field)
        if current is None:
            return False
        try:
            return bool(OPS[self.op](current, self.value))
        except TypeError:
            return False

    def __str__(self) -> str:
        return f"{self.field} {self.op} {_show(self.value)}"


@dataclass(frozen=True)
class Combined:
    kind: Literal["all", "any"]
    parts: tuple[Guard, ...]

    def holds(self, values: Callable[[str], Any]) -> bool:
        results = (part.holds(values) for part in self.parts)
        return all(results) if self.kind == "all" else any(results)

    def which(self, values: Callable[[str], Any]) -> str:
        """The part(s) that hold, for the reason a guard gives."""
        if self.kind == "any":
            for part in self.parts:
                if part.holds(values):
                    return describe_guard(part, values)
        return str(self)

    def __str__(self) -> str:
        joiner = " and " if self.kind == "all" else " or "
        return "(" + joiner.join(str(p) for p in self.parts) + ")"


Guard = Compare | Combined


def describe_guard(guard: Guard, values: Callable[[str], Any]) -> str:
    return guard.which(values) if isinstance(guard, Combined) else str(guard)


def _show(value: Any) -> str:
    return json.dumps(value) if isinstance(value, str) else f"{value:g}" if isinstance(value, float) else str(value).lower() if isinstance(value, bool) else str(value)


def _telemetry_fields() -> dict[str, type]:
    """Every dotted path of Telemetry that holds a scalar, with its type."""
    paths: dict[str, type] = {}

    def walk(kind: type, prefix: str) -> None:
        hints = typing.get_type_hints(kind)
        for name in kind.__struct_fields__:  # type: ignore[attr-defined]
            hint = hints[name]
            if typing.get_origin(hint) is list:
                continue
            args = [a for a in typing.get_args(hint) if a is not type(None)] or [hint]
            inner = args[0]
            if isinstance(inner, type) and issubclass(inner, msgspec.Struct):
                walk(inner, f"{prefix}{name}.")
            elif inner in (int, float, bool, str) or typing.get_origin(inner) is Literal:
                paths[prefix + name] = float if inner is int else (str if typing.get_origin(inner) is Literal else inner)

    walk(Telemetry, "")
    return paths


TELEMETRY_FIELDS = _telemetry_fields()


def parse_guard(obj: Any, path: str) -> Guard:
    """A guard from JSON; InvalidMessage names `path` (e.g. `$.steps[1].until.any[0].op`)."""
    if not isinstance(obj, Mapping):
        raise InvalidMessage(f"{_at(path)}: a guard is an object ({{field, op, value}}, {{all: […]}} or {{any: […]}})", field=path)
    keys = set(obj)
    if keys in ({"all"}, {"any"}):
        combine: Literal["all", "any"] = "all" if "all" in keys else "any"
        parts = obj[combine]
        if not isinstance(parts, list) or not parts:
            raise InvalidMessage(f"{_at(path)}.{combine}: a non-empty list of guards", field=f"{path}.{combine}")
        return Combined(combine, tuple(parse_guard(p, f"{path}.{combine}[{i}]") for i, p in enumerate(parts)))
    if keys != {"field", "op", "value"}:
        extra = sorted(keys - {"field", "op", "value"})
        missing = sorted({"field", "op", "value"} - keys)
        problem = f"unknown key {extra[0]!r}" if extra else f"missing {', '.join(missing)}"
        raise InvalidMessage(f"{_at(path)}: {problem} (a guard is {{field, op, value}}, {{all: […]}} or {{any: […]}})", field=path)
    field, op, value = obj["field"], obj["op"], obj["value"]
    if op not in OPS:
        raise InvalidMessage(f"{_at(path)}.op: {op!r} is not one of {' '.join(OPS)}", field=f"{path}.op")
    if not isinstance(field, str):
        raise InvalidMessage(f"{_at(path)}.field: a dotted name such as sensor.temperature", field=f"{path}.field")
    if field.startswith("sensor."):
        if not field.removeprefix("sensor."):
            raise InvalidMessage(f"{_at(path)}.field: sensor.<type>, e.g. sensor.temperature or sensor.gas.co_ppm",
                                 field=f"{path}.field")
        kind: type | None = None  # whatever the sensor reports
    elif field in TELEMETRY_FIELDS:
        kind = TELEMETRY_FIELDS[field]
    else:
        near = sorted(f for f in TELEMETRY_FIELDS if f.startswith(field.split(".")[0]))
        hint = f"; did you mean {', '.join(near[:4])}?" if near else "; a Telemetry path (battery.remaining_percent, position.rel_alt, speed, …) or sensor.<type>"
        raise InvalidMessage(f"{_at(path)}.field: no field {field!r}{hint}", field=f"{path}.field")
    numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
    if numeric and not math.isfinite(value):
        raise InvalidMessage(f"{_at(path)}.value: must be a finite number", field=f"{path}.value")
    if kind is float and not numeric or kind is bool and not isinstance(value, bool) or kind is str and not isinstance(value, str):
        raise InvalidMessage(f"{_at(path)}.value: {field} is a {kind.__name__ if kind else '?'}, got {value!r}", field=f"{path}.value")
    if op not in ("==", "!=") and not numeric:
        raise InvalidMessage(f"{_at(path)}.op: {op} compares numbers; {value!r} is not one", field=f"{path}.op")
    return Compare(field, op, value)


def _at(path: str) -> str:
    return path.removeprefix("$.")


def sensor_guards(wire: TaskBundle) -> list[tuple[str, str, str]]:
    """Every `sensor.<type>` (or `sensor.<type>.<field>`) a bundle's guards read:
    (JSON path of the field, the label a refusal starts with, `<type>[.<field>]`).
    For the ground's check that the drone carries them."""
    found: list[tuple[str, str, str]] = []

    def walk(obj: Any, path: str, label: str) -> None:
        if not isinstance(obj, Mapping):
            return
        for kind in ("all", "any"):
            for j, part in enumerate(obj.get(kind) or []):
                walk(part, f"{path}.{kind}[{j}]", f"{label}.{kind}[{j}]")
        field = obj.get("field")
        if isinstance(field, str) and field.startswith("sensor."):
            found.append((f"{path}.field", f"{label}.field", field.removeprefix("sensor.")))  # <type>[.<field>]

    for i, step in enumerate(wire.steps):
        walk(step.get("until"), f"$.steps[{i}].until", f"step {i}: until")
    walk(wire.until, "$.until", "until")
    return found


# ---- steps and the parsed bundle ---------------------------------------------------


@dataclass(frozen=True)
class Step:
    command: Command | None  # None: a wait
    wait_s: float | None
    until: Guard | None

    @property
    def name(self) -> str:
        return self.command.name if self.command is not None else "wait"


@dataclass(frozen=True)
class Bundle:
    bundle_id: str
    steps: tuple[Step, ...]
    on_link_loss: LinkLossPolicy
    timeout_s: float | None
    until: Guard | None
    wire: TaskBundle


def parse_bundle(payload: bytes | TaskBundle) -> Bundle:
    """Validate a whole bundle; InvalidMessage names the step and field at fault."""
    if isinstance(payload, TaskBundle):
        wire = payload
    else:
        try:
            wire = msgspec.json.decode(payload, type=TaskBundle)
        except msgspec.ValidationError as exc:
            raise InvalidMessage(str(exc), field=_path_of(str(exc))) from None
        except msgspec.DecodeError as exc:
            raise InvalidMessage(f"malformed JSON: {exc}") from None
    if not wire.bundle_id:
        raise InvalidMessage("bundle_id: must not be empty", field="$.bundle_id")
    if not wire.steps:
        raise InvalidMessage("steps: a bundle needs at least one step", field="$.steps")
    if len(wire.steps) > MAX_STEPS:
        raise InvalidMessage(f"steps: at most {MAX_STEPS}, got {len(wire.steps)}", field="$.steps")
    steps = tuple(_parse_step(obj, i) for i, obj in enumerate(wire.steps))
    until = parse_guard(wire.until, "$.until") if wire.until is not None else None
    return Bundle(wire.bundle_id, steps, wire.on_link_loss, wire.timeout_s, until, wire)


def _parse_step(obj: dict[str, Any], i: int) -> Step:
    where = f"$.steps[{i}]"
    try:
        until = parse_guard(obj["until"], f"{where}.until") if obj.get("until") is not None else None
    except InvalidMessage as exc:
        raise InvalidMessage(exc.reason.replace(f"steps[{i}].", f"step {i}: ", 1), field=exc.field) from None
    body = {k: v for k, v in obj.items() if k not in STEP_FIELDS}
    if "wait_s" in body:
        wait = body.pop("wait_s")
        if body:
            raise InvalidMessage(f"step {i}: a wait step has only wait_s (and until), not {', '.join(sorted(body))}", field=f"{where}.{sorted(body)[0]}")
        if not isinstance(wait, (int, float)) or isinstance(wait, bool) or not 0 <= wait <= 86_400:
            raise InvalidMessage(f"step {i}: wait_s: seconds between 0 and 86400, got {wait!r}", field=f"{where}.wait_s")
        return Step(None, float(wait), until)
    if "cmd" not in body:
        raise InvalidMessage(f"step {i}: a step is a command ({{\"cmd\": …}}) or {{\"wait_s\": N}}", field=where)
    for name in NOT_IN_STEPS:
        if name in body:
            raise InvalidMessage(f"step {i}: {name}: set by the bundle, not in a step", field=f"{where}.{name}")
    if body["cmd"] not in COMMAND_TYPES:
        raise InvalidMessage(f"step {i}: unknown command {body['cmd']!r}; known: {', '.join(COMMAND_TYPES)}", field=f"{where}.cmd")
    try:
        command = decode_command(json.dumps(body, allow_nan=True))
    except InvalidMessage as exc:
        field = f"{where}.{exc.field.removeprefix('$.')}" if exc.field else where
        raise InvalidMessage(f"step {i}: {exc.reason}", field=field) from None
    return Step(command, None, until)


def _path_of(text: str) -> str | None:
    start = text.find("`$")
    return text[start + 1:text.index("`", start + 1)] if start >= 0 else None
