"""What a mission script sees: verbs, the drone wrapper, units, geo and channels (SPEC §5).

Every verb blocks its subroutine (never the loop) until its effect is done: `move`
returns when the drone has arrived, `arm` when the autopilot armed — and the first
telemetry after that has arrived, so `drone.position` or `drone.armed` read right
after a verb show its effect. Relative moves
are planned from where the previous verb left the drone — its last target and
heading while it is still there — so a survey visits exactly the waypoints it
describes instead of accumulating each stop's acceptance-radius error.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from typing import Any

from greenlet import getcurrent

from mission import assignment as a
from mission import geo, units
from mission.geo import Position, as_position
from mission.mission import Mission, MissionOver
from mission.relaying import Relays
from mission.runtime import Stopped, Subroutine, await_
from mission.sandbox import Guards
from schemas.errors import CommandRejected
from schemas.geo import angle_diff_deg, normalize_deg
from schemas.telemetry import LinkQuality

COMPLETED = frozenset({"success", "finish"})
MIN_HANDOVER_HEIGHT_M = 2.0
# An idle drone this close to its last target (by telemetry up to a period old, at
# cruise speed) plans from that target.
ANCHOR_RADIUS_M = 10.0
DEFAULT_BUNDLE_TIMEOUT_S = 600.0  # push(timeout=…): how long a bundle may run before the drone gives up


class _AnyDrone:
    __slots__ = ()

    def __repr__(self) -> str:
        return "any_drone"


any_drone = _AnyDrone()


def guarded(fn: Callable[..., Any]) -> Callable[..., Any]:
    """A verb as scripts see it: a mission that ends unwinds the caller (uncatchably)."""

    def verb(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except MissionOver:
            raise Stopped() from None

    verb.__name__ = fn.__name__
    verb.__doc__ = fn.__doc__
    return verb


def _call(mission: Mission, awaitable: Any) -> Any:
    """Run a mission coroutine from a script; a mission that ends unwinds the caller."""
    try:
        return await_(awaitable)
    except MissionOver:
        raise Stopped() from None


class CommandView:
    """`drone.cmd`: the drone's current command, with `.target` for takeoff/goto/move."""

    __slots__ = ("description", "name", "target")

    def __init__(self, name: str, description: str, target: Position | float | None) -> None:
        self.name = name
        self.description = description
        self.target = target

    def as_position(self) -> Position:
        if not isinstance(self.target, Position):
            raise ValueError(f"the current command ({self.description}) has no target position")
        return self.target

    def distance(self, other: Any) -> float:
        return self.as_position().distance(other)

    def bearing(self, other: Any) -> float:
        return self.as_position().bearing(other)

    def __repr__(self) -> str:
        return f"<cmd {self.description}>"


class SensorView:
    """`drone.sensor.temperature`: the latest reading of that type, or None."""

    __slots__ = ("_drone",)

    def __init__(self, drone: Drone) -> None:
        self._drone = drone

    def __getattr__(self, kind: str) -> Any:
        if kind.startswith("_"):
            raise AttributeError(kind)
        for reading in self._drone._m.station.registry.sensor_readings(self._drone._live()):
            if reading.type == kind:
                return reading.value
        return None


class Drone:
    """The drone wrapper (thesis table 5.4). It keeps its identity across `replace`."""

    __slots__ = ("_anchor", "_gen", "_handover", "_handover_owner", "_id", "_m", "sensor")

    def __init__(self, mission: Mission, drone_id: str) -> None:
        self._m = mission
        self._id = drone_id
        self._anchor: Position | None = None
        self._gen = 0  # bumped by every replacement: a verb that spans one redoes its command
        self._handover: asyncio.Future[None] | None = None  # set while `replace` brings the new drone in
        self._handover_owner: Any = None
        self.sensor = SensorView(self)

    def _live(self) -> str:
        """The drone behind the wrapper now; waits while a replacement is handing over."""
        handover = self._handover
        if handover is not None and getcurrent() is not self._handover_owner:
            _call(self._m, asyncio.shield(handover))
        try:
            self._m.check_assigned(self._id)
        except MissionOver:
            raise Stopped() from None
        return self._id

    def _telem(self) -> Any:
        return self._m.station.registry.telemetry(self._live())

    def __repr__(self) -> str:
        return f"<drone {self._id}>"

    @property
    def id(self) -> str:
        return self._id

    @property
    def state(self) -> str:
        return self._m.station.registry.info(self._live()).state

    @property
    def armed(self) -> bool:
        return bool(self._telem().armed)

    @property
    def battery(self) -> float:
        t = self._telem()
        return t.battery.remaining_percent if t.battery else 0.0

    @property
    def heading(self) -> float:
        return float(self._telem().heading)

    @property
    def speed(self) -> float:
        return float(self._telem().speed)

    @property
    def position(self) -> Position:
        t = self._telem()
        if t.position is None:
            raise ValueError(f"{self._id} reports no position")
        return Position(t.position.lat, t.position.lon, t.position.alt, t.heading)

    @property
    def rel_alt(self) -> float:
        t = self._telem()
        return t.position.rel_alt if t.position else 0.0

    @property
    def home(self) -> Position | None:
        h = self._telem().home
        return Position(h.lat, h.lon, h.alt) if h else None

    @property
    def cmd(self) -> CommandView | None:
        current = self._m.station.registry.info(self._live()).current_command
        if current is None:
            return None
        c = current.command
        target: Position | float | None = None
        if current.coords is not None:
            target = Position(current.coords.lat, current.coords.lon, current.coords.alt)
        elif c in ("takeoff", "return") and current.altitude is not None:
            target = current.altitude
        return CommandView(c, current.description, target)

    @property
    def link(self) -> LinkQuality | None:
        """The drone's measured link to the ground (`.quality`, `.rtt_ms`, `.jitter_ms`,
        `.loss`), or None before its first probe report."""
        return self._m.station.registry.info(self._live()).link

    def as_position(self) -> Position:
        return self.position

    # geo shortcuts on the drone itself
    def distance(self, other: Any) -> float:
        return self.position.distance(other)

    def bearing(self, other: Any) -> float:
        return self.position.bearing(other)

    def target(self, dist: Any, bearing: Any) -> Position:
        return self.position.target(dist, bearing)

    def forward(self, d: Any) -> Position:
        return self._plan_base().forward(d)

    def backward(self, d: Any) -> Position:
        return self._plan_base().backward(d)

    def left(self, d: Any) -> Position:
        return self._plan_base().left(d)

    def right(self, d: Any) -> Position:
        return self._plan_base().right(d)

    def up(self, d: Any) -> Position:
        return self._plan_base().up(d)

    def down(self, d: Any) -> Position:
        return self._plan_base().down(d)

    def _plan_base(self) -> Position:
        """Where the next relative move or turn starts.

        While the drone idles where its last verb left it, that verb's target (and
        heading) — exact, unlike telemetry up to one period old. Otherwise the next
        fresh telemetry sample, so a heading caught mid-turn is never used.
        """
        anchored = self._anchored()
        if anchored is not None:
            return anchored
        _call(self._m, self._m.next_telemetry(self._live()))
        return self.position

    def _anchored(self) -> Position | None:
        """The last verb's target, if the drone idles there."""
        anchor = self._anchor
        if anchor is not None and self._m.station.registry.info(self._live()).current_command is None:
            here = self.position
            if here.distance(anchor) <= ANCHOR_RADIUS_M:
                alt = anchor.alt if anchor.alt is not None else here.alt
                return Position(anchor.lat, anchor.lon, alt, anchor.heading)
        return None


class Channel:
    """`channel.name = v` binds once; reading `channel.name` blocks until bound."""

    def __init__(self, mission: Mission) -> None:
        object.__setattr__(self, "_m", mission)
        object.__setattr__(self, "_values", {})
        object.__setattr__(self, "_waiters", {})

    def __setattr__(self, name: str, value: Any) -> None:
        values: dict[str, Any] = object.__getattribute__(self, "_values")
        if name in values:
            if values[name] == value:
                return
            raise ValueError(f"channel.{name} is already bound to {values[name]!r}")
        values[name] = value
        waiters: dict[str, list[Any]] = object.__getattribute__(self, "_waiters")
        for fut in waiters.pop(name, []):
            if not fut.done():
                fut.set_result(value)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        values: dict[str, Any] = object.__getattribute__(self, "_values")
        if name in values:
            return values[name]
        fut = asyncio.get_running_loop().create_future()
        object.__getattribute__(self, "_waiters").setdefault(name, []).append(fut)
        return _call(object.__getattribute__(self, "_m"), fut)


class GuardSpec:
    """A bundle guard as data (SPEC §6): `when.sensor.temperature > 37`, combined with
    `&` (all) and `|` (any). The drone compares; nothing here runs on the drone."""

    def __init__(self, data: dict[str, Any]) -> None:
        self.data = data

    def __and__(self, other: GuardSpec) -> GuardSpec:
        return GuardSpec({"all": [self.data, _guard(other)]})

    def __or__(self, other: GuardSpec) -> GuardSpec:
        return GuardSpec({"any": [self.data, _guard(other)]})

    def __ror__(self, other: Any) -> GuardSpec:
        raise TypeError("guards: put each comparison in parentheses, e.g. (when.sensor.temperature > 37) | (when.battery.remaining_percent < 0.3)")

    __rand__ = __ror__

    def __repr__(self) -> str:
        return f"GuardSpec({self.data})"


def _guard(value: Any) -> dict[str, Any]:
    if not isinstance(value, GuardSpec):
        raise TypeError(f"until: expected a guard such as when.sensor.temperature > 37, got {value!r}")
    return value.data


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
            body["until"] = _guard(until)
        return body

    def arm(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "arm"}, until)

    def disarm(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "disarm"}, until)

    def takeoff(self, alt: Any = None, until: Any = None) -> dict[str, Any]:
        body: dict[str, Any] = {"cmd": "takeoff"}
        if alt is not None:
            body["alt"] = units.length(alt, "takeoff altitude")
        return self._step(body, until)

    def land(self, until: Any = None) -> dict[str, Any]:
        return self._step({"cmd": "land"}, until)

    def home(self, alt: Any = None, until: Any = None) -> dict[str, Any]:
        body: dict[str, Any] = {"cmd": "return"}
        if alt is not None:
            body["alt"] = units.length(alt, "return altitude")
        return self._step(body, until)

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


def build_namespace(mission: Mission, guards: Guards) -> dict[str, Any]:
    """The globals one mission script runs with."""
    m = mission
    clock = mission.clock

    def drone_id(d: Any) -> str:
        if not isinstance(d, Drone):
            raise TypeError(f"expected a drone (from assign), got {d!r}")
        return d._live()

    def send(d: Drone, body: dict[str, Any], wait: bool = True, wait_clear: bool = False) -> Any:
        target, generation = drone_id(d), d._gen
        status = _call(m, m.execute(target, body, wait=wait, wait_clear=wait_clear))
        if wait and d._gen != generation and status.state not in COMPLETED:
            # `replace` swapped the drone while it ran this command (the return home
            # superseded it): the new drone, once in place, does it instead.
            target = drone_id(d)
            m.log("info", f"{target} takes over the interrupted {body['cmd']}")
            status = _call(m, m.execute(target, body, wait=True))
        if wait:  # the wrapper then shows the effect (telemetry after completion)
            _call(m, m.next_telemetry(d._live()))
        return status

    # ---- assignment ----------------------------------------------------------------

    def request_of(item: Any) -> a.Request:
        if isinstance(item, str):
            return a.ById(item)
        if item is any_drone or item is None:
            return a.AnyDrone()
        if isinstance(item, (a.ById, a.BySensors, a.Near, a.ByKind, a.AnyRelay, a.AnyDrone)):
            return item
        raise TypeError(f"assign: expected a drone id, any_drone, with_sensors(…), near(…) or of_kind(…), got {item!r}")

    def assign(*items: Any, sensor: str | None = None, sensors: list[str] | None = None,
               near: Any = None, kind: str | None = None) -> Any:
        requests = [request_of(i) for i in items]
        if sensor is not None or sensors is not None:
            requests.append(a.BySensors(frozenset(([sensor] if sensor else []) + list(sensors or []))))
        if near is not None:
            requests.append(near_place(near))
        if kind is not None:
            requests.append(a.ByKind(kind))
        if not requests:
            requests = [a.AnyDrone()]
        drones = [Drone(m, i) for i in _call(m, m.assign(requests))]
        for wrapper in drones:
            m.add_wrapper(wrapper)
        return drones[0] if len(drones) == 1 else tuple(drones)

    def revoke(d: Drone) -> None:
        m.revoke(drone_id(d))
        m.drop_wrapper(d)

    def replace(d: Drone) -> Drone:
        """Send `d` home and put the closest free drone in its place, same wrapper.

        A flying drone is handed over: the new one arms, takes off to the old one's
        height and flies to where it stopped (its last waypoint if it idled there),
        facing the same way; `replace` returns then. Meanwhile every other use of the
        wrapper waits, and a command the old drone was running when it was sent home
        is done again by the new one — so a survey continues where it was cut.
        """
        old = drone_id(d)
        new = m.replacement_for(old)
        request = m.requests[old]
        t = m.station.registry.telemetry(old)
        flying = t.armed and t.landed_state != "on_ground"
        stop_at = d._anchored() or d.position
        height = d.rel_alt
        d._gen += 1
        d._handover = asyncio.get_running_loop().create_future()
        d._handover_owner = getcurrent()
        try:
            send(d, {"cmd": "return"}, wait=False)
            m.revoke(old)
            try:
                _call(m, m.take(new, request))
            except CommandRejected as exc:  # another mission claimed it first (missions in their own processes)
                raise m.fail("requirements", f"{new} could not replace {old}: {exc.reason}") from None
            d._id = new
            d._anchor = None
            if not flying:
                m.log("info", f"Replaced {old} with {new}")
                return d
            m.log("info", f"Replaced {old} with {new}: {new} takes over at {stop_at.lat:.6f}, {stop_at.lon:.6f}")
            arm(d)
            takeoff(d, max(height, MIN_HANDOVER_HEIGHT_M))
            body: dict[str, Any] = {"cmd": "goto", "lat": stop_at.lat, "lon": stop_at.lon, "alt": stop_at.alt}
            if stop_at.heading is not None:
                body["yaw"] = stop_at.heading
            send(d, body)
            d._anchor = stop_at
            return d
        finally:
            handover, d._handover, d._handover_owner = d._handover, None, None
            if not handover.done():
                handover.set_result(None)

    # ---- commands ------------------------------------------------------------------

    def arm(d: Drone) -> None:
        send(d, {"cmd": "arm"})

    def disarm(d: Drone) -> None:
        send(d, {"cmd": "disarm"})

    def takeoff(d: Drone, alt: Any = None) -> None:
        body: dict[str, Any] = {"cmd": "takeoff"}
        if alt is not None:
            body["alt"] = units.length(alt, "takeoff altitude")
        send(d, body)
        d._anchor = None

    def land(d: Drone) -> None:
        send(d, {"cmd": "land"})
        d._anchor = None

    def home(d: Drone, alt: Any = None) -> None:
        body: dict[str, Any] = {"cmd": "return"}
        if alt is not None:
            body["alt"] = units.length(alt, "return altitude")
        send(d, body)
        d._anchor = None

    def cancel(d: Drone) -> None:
        send(d, {"cmd": "cancel"})

    def turn(d: Drone, by: Any = None, to: Any = None) -> None:
        if (by is None) == (to is None):
            raise TypeError("turn: give exactly one of by= (degrees) or to= (a direction, angle or position)")
        base = d._plan_base()
        if by is not None:
            goal = normalize_deg(base.heading + units.angle(by, "turn by"))
        elif isinstance(to, (units.Quantity, int, float)) and not isinstance(to, bool):
            goal = normalize_deg(units.angle(to, "turn to"))
        else:
            goal = base.bearing(to)
        delta = angle_diff_deg(goal, base.heading)
        send(d, {"cmd": "turn", "deg": delta})
        d._anchor = Position(base.lat, base.lon, base.alt, goal)

    def move(d: Drone, *, forward: Any = 0, backward: Any = 0, right: Any = 0, left: Any = 0,
             up: Any = 0, down: Any = 0, to: Any = None, lat: Any = None, lon: Any = None,
             alt: Any = None, yaw: Any = None, speed: Any = None, wait_clear: bool = False) -> None:
        goal = move_goal("move", forward, backward, right, left, up, down, to, lat, lon)
        # Where the drone is now matters only to a relative move or one that keeps its
        # heading; an absolute one with a yaw goes at once (no wait for telemetry).
        base = d._plan_base() if isinstance(goal, tuple) or yaw is None else None
        if isinstance(goal, tuple):
            assert base is not None
            fwd, rgt, vertical = goal
            moved = base.forward(fwd).right(rgt) if (fwd or rgt) else base
            goal = Position(moved.lat, moved.lon, (base.alt or 0.0) + vertical, base.heading)
        if alt is not None:
            goal = Position(goal.lat, goal.lon, alt, goal.heading)
        body: dict[str, Any] = {"cmd": "goto", "lat": goal.lat, "lon": goal.lon}
        if goal.alt is not None:
            body["alt"] = goal.alt
        if yaw is not None:
            heading = normalize_deg(units.angle(yaw, "yaw"))
            body["yaw"] = heading
        else:
            assert base is not None
            heading = base.heading
        if speed is not None:
            body["speed"] = units.speed(speed)
        send(d, body, wait_clear=bool(wait_clear))
        d._anchor = Position(goal.lat, goal.lon, goal.alt, heading)

    # ---- task bundles (SPEC §6) ------------------------------------------------------

    def push(d: Drone, steps: Any, on_link_loss: str = "continue", timeout: Any = DEFAULT_BUNDLE_TIMEOUT_S,
             until: Any = None) -> Any:
        """Hand `d` a list of steps (from `step.…`) to run on its own; block until the
        bundle has ended and return the drone's record of it (`.state` done | ended |
        failed | cancelled, `.step`, `.steps_done`, `.ended_by`, `.reason`, `.history`).
        While the drone is out of reach the mission waits for it: working alone is
        not a failure until `timeout` plus mission.link_grace_s have passed."""
        if not isinstance(steps, (list, tuple)) or not steps:
            raise TypeError("push: steps is a non-empty list of step.…(…) items")
        body: dict[str, Any] = {"steps": list(steps), "on_link_loss": on_link_loss}
        if timeout is not None:
            body["timeout_s"] = units.duration(timeout, "timeout")
        if until is not None:
            body["until"] = _guard(until)
        record = _call(m, m.push(drone_id(d), body))
        d._anchor = None
        _call(m, m.next_telemetry(d._live()))
        return record

    # ---- time and concurrency ------------------------------------------------------

    def sleep(duration: Any) -> None:
        _call(m, clock.sleep(units.duration(duration, "sleep")))

    def run(fn: Callable[..., Any], *args: Any) -> Subroutine:
        if not callable(fn):
            raise TypeError(f"run: expected a function, got {fn!r}")
        assert m.scheduler is not None
        return m.scheduler.spawn(fn, *args)

    def wait(*things: Any) -> None:
        for thing in things:
            if isinstance(thing, Drone):
                _call(m, m.next_telemetry(drone_id(thing)))
            elif isinstance(thing, Subroutine):
                if thing.running:
                    _call(m, asyncio.wait([thing._done]))
            elif isinstance(thing, (list, tuple)):
                wait(*thing)
            else:
                raise TypeError(f"wait: expected drones or subroutines, got {thing!r}")

    def stop(*subs: Subroutine) -> None:
        assert m.scheduler is not None
        for sub in subs:
            if not isinstance(sub, Subroutine):
                raise TypeError(f"stop: expected a subroutine (from run), got {sub!r}")
            m.scheduler.stop(sub)

    # ---- plugins (mission/plugins.py) ----------------------------------------------

    def enable(plugin_id: str, **inputs: Any) -> None:
        """Enable a loaded plugin for this mission with its inputs (typed, defaults apply)."""
        m.plugins.enable(plugin_id, inputs, base, namespace)

    def disable(plugin_id: str) -> None:
        m.plugins.disable(plugin_id, namespace)

    defined = locals()
    verbs: dict[str, Any] = {name: guarded(defined[name]) for name in VERBS}
    base = common_names(guards)  # what a plugin enabled by this mission sees
    base.update(verbs)
    base.update(channel=Channel(m), mission_id=m.id, step=Steps(), when=When(),
                relays=Relays(m))
    namespace = dict(base)  # the script's globals
    return namespace


# The DSL's verbs (SPEC §5): the one list. build_namespace binds each name to the
# function of that name it defines, so a verb cannot be listed without existing.
VERBS = (
    "assign", "revoke", "replace", "arm", "disarm", "takeoff", "land", "home", "cancel", "turn",
    "move", "push", "sleep", "run", "wait", "stop", "enable", "disable",
)
VERB_NAMES = (*VERBS, "channel", "mission_id", "step", "when")  # every name a mission script gets from its mission


def common_names(guards: Guards) -> dict[str, Any]:
    """What every script sees besides the verbs: builtins, units, geo, directions."""
    namespace: dict[str, Any] = {
        "__builtins__": guards.builtins(),
        "__name__": "mission",
        **guards.hooks(),
        "any_drone": any_drone,
        "any_relay": a.AnyRelay(),
        "with_sensors": lambda *kinds: a.BySensors(frozenset(kinds)),
        "near": near_place,
        "of_kind": a.ByKind,
        "position": geo.position,
        "distance": geo.distance,
        "bearing": geo.bearing,
        "target": geo.target,
        "north": 0 * units.deg,
        "east": 90 * units.deg,
        "south": 180 * units.deg,
        "west": 270 * units.deg,
        "pi": math.pi,
        "relays": Relays(),
    }
    namespace.update(units.UNITS)
    return namespace


def near_place(place: Any) -> a.Near:
    """`assign(near(coords))`: the free drone closest to a place."""
    p = as_position(place)
    return a.Near(p.lat, p.lon)
