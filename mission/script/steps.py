"""The bundle-step builders a mission script uses for `push` (SPEC §6): `step.move(...)`
and the others, and `when`, which writes a step's guard (`when.sensor.temperature > 60`)."""

from __future__ import annotations

from typing import Any

from dronefleet.mission.script import units
from dronefleet.mission.script.position import Position, as_position
from dronefleet.schemas.geo import normalize_deg


class GuardSpec:
    """A bundle guard as data (SPEC §6): `when.sensor.temperature > 37`, combined with
    `&` (all) and `|` (any). The drone compares; nothing here runs on the drone."""

    def __init__(self, data: dict[str, Any]) -> None:
        self.data = data

    def __and__(self, other: GuardSpec) -> GuardSpec:
        return GuardSpec({"all": [self.data, as_guard(other)]})

    def __or__(self, other: GuardSpec) -> GuardSpec:
        return GuardSpec({"any": [self.data, as_guard(other)]})

    def __ror__(self, other: Any) -> GuardSpec:
        raise TypeError("guards: put each comparison in parentheses, e.g. (when.sensor.temperature > 37) | (when.battery.remaining_percent < 0.3)")

    __rand__ = __ror__

    def __repr__(self) -> str:
        return f"GuardSpec({self.data})"


def as_guard(value: Any) -> dict[str, Any]:
    if not isinstance(value, GuardSpec):
        raise TypeError(f"until: expected a guard such as when.sensor.temperature > 37, got {value!r}")
    return value.data


def sensor_guards(body: Any) -> list[str]:
    """The sensors a bundle's guards compare (`when.sensor.gas.co_ppm > 50`: "gas"), in
    the order they first appear, anywhere in its steps and its own `until`."""
    found: list[str] = []

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            field = node.get("field")
            if isinstance(field, str) and field.startswith("sensor.") and (kind := field.split(".")[1]) not in found:
                found.append(kind)
            for value in node.values():
                walk(value)
        elif isinstance(node, (list, tuple)):
            for item in node:
                walk(item)

    walk(body)
    return found


class When:
    """`when.<dotted telemetry field>` or `when.sensor.<type>`, compared to a value."""

    def __init__(self, path: tuple[str, ...] = ()) -> None:
        object.__setattr__(self, "_path", path)

    def __getattr__(self, name: str) -> When:
        if name.startswith("_"):
            raise AttributeError(name)
        return When((*object.__getattribute__(self, "_path"), name))

    def _compare(self, op: str, value: Any) -> GuardSpec:
        path = object.__getattribute__(self, "_path")
        if not path:
            raise TypeError("when: name a field, e.g. when.battery.remaining_percent < 0.3")
        plain = value.value if isinstance(value, units.Quantity) else value
        return GuardSpec({"field": ".".join(path), "op": op, "value": plain})

    def __lt__(self, value: Any) -> GuardSpec:
        return self._compare("<", value)

    def __le__(self, value: Any) -> GuardSpec:
        return self._compare("<=", value)

    def __gt__(self, value: Any) -> GuardSpec:
        return self._compare(">", value)

    def __ge__(self, value: Any) -> GuardSpec:
        return self._compare(">=", value)

    def __eq__(self, value: Any) -> GuardSpec:  # type: ignore[override]
        return self._compare("==", value)

    def __ne__(self, value: Any) -> GuardSpec:  # type: ignore[override]
        return self._compare("!=", value)

    __hash__ = None  # type: ignore[assignment]


ALTITUDE_OF = {"takeoff": "takeoff altitude", "return": "return altitude"}


def altitude_body(cmd: str, alt: Any) -> dict[str, Any]:
    """The body of a takeoff or a return, with its altitude (a length) when one is given:
    the mission verbs and the bundle steps send the same."""
    body: dict[str, Any] = {"cmd": cmd}
    if alt is not None:
        body["alt"] = units.length(alt, ALTITUDE_OF[cmd])
    return body


def move_goal(verb: str, forward: Any, backward: Any, right: Any, left: Any, up: Any, down: Any,
              to: Any, lat: Any, lon: Any) -> Position | tuple[float, float, float]:
    """What `move` / `step.move` was asked: a destination (a Position), or offsets in
    metres (forward, right, up) relative to the drone's heading."""
    relative = any(v != 0 for v in (forward, backward, right, left, up, down))
    if to is not None or lat is not None or lon is not None:
        if relative:
            raise TypeError(f"{verb}: give either a position (to=/lat=/lon=) or directions, not both")
        if to is not None:
            return as_position(to)
        if lat is None or lon is None:
            raise TypeError(f"{verb}: lat= and lon= go together")
        return Position(lat, lon)
    if relative:
        return (units.length(forward, "forward") - units.length(backward, "backward"),
                units.length(right, "right") - units.length(left, "left"),
                units.length(up, "up") - units.length(down, "down"))
    raise TypeError(f"{verb}: give a destination (to=, lat=/lon=) or a direction (forward=, right=, up=, …)")


class Steps:
    """`step.move(...)`, `step.wait(...)`…: the steps of a bundle, built with the verbs'
    helpers (units, positions, directions). Each takes `until=` to end it early."""

    @staticmethod
    def _step(body: dict[str, Any], until: Any) -> dict[str, Any]:
        if until is not None:
            body["until"] = as_guard(until)
        return body

    def arm(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "arm"}, until)

    def disarm(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "disarm"}, until)

    def takeoff(self, alt: Any = None, until: Any = None) -> dict[str, Any]:
        return self._step(altitude_body("takeoff", alt), until)

    def land(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "land"}, until)

    def home(self, alt: Any = None, until: Any = None) -> dict[str, Any]:
        return self._step(altitude_body("return", alt), until)

    def hold(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "cancel"}, until)

    def turn(self, by: Any, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "turn", "deg": units.angle(by, "turn by")}, until)

    def wait(self, duration: Any, until: Any = None) -> dict[str, Any]:
        return self._step({"wait_s": units.duration(duration, "wait")}, until)

    def move(self, *, forward: Any = 0, backward: Any = 0, right: Any = 0, left: Any = 0, up: Any = 0, down: Any = 0,
             to: Any = None, lat: Any = None, lon: Any = None, alt: Any = None, yaw: Any = None, speed: Any = None,
             until: Any = None) -> dict[str, Any]:
        """To a position (to=, lat=/lon=, alt=) — or by offsets from wherever the drone
        is when the step starts (forward=, right=, up=, …: relative to its heading)."""
        goal = move_goal("step.move", forward, backward, right, left, up, down, to, lat, lon)
        body: dict[str, Any]
        if isinstance(goal, tuple):
            fwd, rgt, vertical = goal
            body = {"cmd": "move", "x": rgt, "y": fwd, "z": vertical}
        else:
            body = {"cmd": "goto", "lat": goal.lat, "lon": goal.lon}
            height = alt if alt is not None else goal.alt
            if height is not None:
                body["alt"] = units.length(height, "alt")
            if yaw is not None:
                body["yaw"] = normalize_deg(units.angle(yaw, "yaw"))
        if speed is not None:
            body["speed"] = units.speed(speed)
        return self._step(body, until)
