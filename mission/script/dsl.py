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
import inspect
from collections.abc import Callable
from typing import Any

from greenlet import getcurrent

from dronefleet.mission.lifecycle import assignment as a
from dronefleet.mission.lifecycle.greenlets import Subroutine
from dronefleet.mission.script import units
from dronefleet.mission.script.activity import reported
from dronefleet.mission.script.channel import Channel
from dronefleet.mission.script.drone import (
    COMPLETED,
    MIN_HANDOVER_HEIGHT_M,
    Drone,
    any_drone,
    call,
    guarded,
    handle,
    unknowable,
)
from dronefleet.mission.script.field_sensors import FieldSensor, field_sensors_of
from dronefleet.mission.script.host import ScriptHost
from dronefleet.mission.script.names import VERBS, common_names, near_place
from dronefleet.mission.script.position import Position
from dronefleet.mission.script.relaying import Relays
from dronefleet.mission.script.sandbox import Guards
from dronefleet.mission.script.steps import Steps, When, altitude_body, as_guard, move_goal, sensor_guards
from dronefleet.mission.script.units import Angle, Distance, Duration, Speed
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.geo import angle_diff_deg, normalize_deg

DEFAULT_BUNDLE_TIMEOUT_S = 600.0  # push(timeout=…): how long a bundle may run before the drone gives up


class Verbs:
    """The DSL's verbs (SPEC §5) for one mission: each public method is the verb of its
    name (`names.VERBS`), as scripts call it; their signatures are what `fleet mission
    check` holds calls to (mission/script/checks.py)."""

    def __init__(self, mission: ScriptHost) -> None:
        self.m = mission
        self.base: dict[str, Any] = {}  # what a plugin enabled by this mission sees
        self.namespace: dict[str, Any] = {}  # the script's globals

    def _drone_id(self, d: Any) -> str:
        if not isinstance(d, Drone):
            raise TypeError(f"expected a drone (from assign), got {d!r}")
        return handle(d).live()

    def _send(self, d: Drone, body: dict[str, Any], wait: bool = True, wait_clear: bool = False) -> Any:
        target, generation = self._drone_id(d), handle(d).generation
        status = call(self.m, self.m.delivery.execute(target, body, wait=wait, wait_clear=wait_clear))
        if wait and handle(d).generation != generation and status.state not in COMPLETED:
            # `replace` swapped the drone while it ran this command (the return home
            # superseded it): the new drone, once in place, does it instead.
            target = self._drone_id(d)
            self.m.log("info", f"{target} takes over the interrupted {body['cmd']}")
            status = call(self.m, self.m.delivery.execute(target, body, wait=True))
        if wait:  # the wrapper then shows the effect (telemetry after completion)
            call(self.m, self.m.next_telemetry(handle(d).live()))
        return status

    # ---- assignment ----------------------------------------------------------------

    def _request_of(self, item: Any) -> a.Request:
        if isinstance(item, str):
            return a.ById(item)
        if item is any_drone or item is None:
            return a.AnyDrone()
        if isinstance(item, (a.ById, a.BySensors, a.Near, a.ByKind, a.ByRole, a.AnyRelay, a.AnyDrone, a.AllOf)):
            return item
        raise TypeError("assign: expected a drone id, any_drone, any_relay, with_sensors(…), near(…), of_kind(…) "
                        f"or with_role(…), got {item!r}")

    def assign(self, *items: Any, sensor: str | None = None, sensors: list[str] | None = None,
               near: Any = None, kind: str | None = None, role: str | None = None) -> Any:
        """Positional items ask for one drone each; the keywords together describe one
        drone more (`assign(sensor="gas", role="survey", near=pos)`: the nearest survey
        drone carrying gas)."""
        requests = [self._request_of(i) for i in items]
        described: list[a.Part] = []
        if sensor is not None or sensors is not None:
            described.append(a.BySensors(frozenset(([sensor] if sensor else []) + list(sensors or []))))
        if near is not None:
            described.append(near_place(near))
        if kind is not None:
            described.append(a.ByKind(kind))
        if role is not None:
            described.append(a.ByRole(role))
        if len(described) > 1:
            requests.append(a.AllOf(tuple(described)))
        else:
            requests.extend(described)
        if not requests:
            requests = [a.AnyDrone()]
        drones = [Drone(self.m, i) for i in call(self.m, self.m.assign(requests))]
        for wrapper in drones:
            self.m.add_wrapper(wrapper)
        return drones[0] if len(drones) == 1 else tuple(drones)

    def revoke(self, d: Drone) -> None:
        """Give `d` back: the mission no longer commands it and another mission may assign it."""
        self.m.revoke(self._drone_id(d))
        self.m.drop_wrapper(d)

    def replace(self, d: Drone) -> Drone:
        """Send `d` home and put the closest free drone in its place, same wrapper.

        A flying drone is handed over: the new one arms, takes off to the old one's
        height and flies to where it stopped (its last waypoint if it idled there),
        facing the same way; `replace` returns then. Meanwhile every other use of the
        wrapper waits, and a command the old drone was running when it was sent home
        is done again by the new one — so a survey continues where it was cut.
        """
        old = self._drone_id(d)
        new = self.m.replacement_for(old)
        request = self.m.requests[old]
        t = self.m.station.registry.telemetry(old)
        flying = t.armed and t.landed_state != "on_ground"
        h = handle(d)
        stop_at = h.anchored() or d.position
        height = d.rel_alt
        h.generation += 1
        h.handover = asyncio.get_running_loop().create_future()
        h.handover_owner = getcurrent()
        try:
            self._send(d, {"cmd": "return"}, wait=False)
            self.m.revoke(old)
            try:
                call(self.m, self.m.take(new, request))
            except CommandRejected as exc:  # another mission claimed it first (missions in their own processes)
                raise self.m.fail("requirements", f"{new} could not replace {old}: {exc.reason}") from None
            h.drone_id = new
            h.anchor = None
            if not flying:
                self.m.log("info", f"Replaced {old} with {new}")
                return d
            self.m.log("info", f"Replaced {old} with {new}: {new} takes over at {stop_at.lat:.6f}, {stop_at.lon:.6f}")
            self.arm(d)
            self.takeoff(d, max(height, MIN_HANDOVER_HEIGHT_M))
            body: dict[str, Any] = {"cmd": "goto", "lat": stop_at.lat, "lon": stop_at.lon, "alt": stop_at.alt}
            if stop_at.heading is not None:
                body["yaw"] = stop_at.heading
            self._send(d, body)
            h.anchor = stop_at
            return d
        finally:
            handover, h.handover, h.handover_owner = h.handover, None, None
            if not handover.done():
                handover.set_result(None)

    # ---- commands ------------------------------------------------------------------

    def arm(self, d: Drone) -> None:
        """Arm `d`; returns once its autopilot reports it armed (refused: the mission says why)."""
        self._send(d, {"cmd": "arm"})

    def disarm(self, d: Drone) -> None:
        """Disarm `d` (on the ground)."""
        self._send(d, {"cmd": "disarm"})

    def takeoff(self, d: Drone, alt: Distance = None) -> None:
        """Take off to `alt` above home (default: the agent's takeoff altitude); returns at that height."""
        self._send(d, altitude_body("takeoff", alt))
        handle(d).anchor = None

    def land(self, d: Drone) -> None:
        """Land where `d` is; returns once it is on the ground."""
        self._send(d, {"cmd": "land"})
        handle(d).anchor = None

    def home(self, d: Drone, alt: Distance = None) -> None:
        """Fly `d` home (at `alt` above home, default its return altitude) and land it there."""
        self._send(d, altitude_body("return", alt))
        handle(d).anchor = None

    def cancel(self, d: Drone) -> None:
        """Stop what `d` is doing (a goto, a move, a return): it holds where it is."""
        self._send(d, {"cmd": "cancel"})

    def turn(self, d: Drone, by: Angle = None, to: Any = None) -> None:
        """Turn `d` in place: `by` degrees clockwise, or `to` a heading, an angle or a position to face."""
        if (by is None) == (to is None):
            raise TypeError("turn: give exactly one of by= (degrees) or to= (a direction, angle or position)")
        base = handle(d).plan_base()
        if by is not None:
            goal = normalize_deg(base.heading + units.angle(by, "turn by"))
        elif isinstance(to, (units.Quantity, int, float)) and not isinstance(to, bool):
            goal = normalize_deg(units.angle(to, "turn to"))
        else:
            goal = base.bearing(to)
        delta = angle_diff_deg(goal, base.heading)
        self._send(d, {"cmd": "turn", "deg": delta})
        handle(d).anchor = Position(base.lat, base.lon, base.alt, goal)

    def move(self, d: Drone, *, forward: Distance = 0, backward: Distance = 0, right: Distance = 0, left: Distance = 0,
             up: Distance = 0, down: Distance = 0, to: Any = None, lat: Any = None, lon: Any = None,
             alt: Any = None, yaw: Angle = None, speed: Speed = None, wait_clear: bool = False) -> None:
        """Fly `d` relative to where it faces (`forward`, `right`, `up`, …, combined) or
        `to` a position (or `lat`/`lon`); `alt` sets the altitude AMSL, `yaw` the heading
        (default: keep it), `speed` the speed. Returns on arrival. A target within
        `min_separation_m` of another drone's is refused (`conflict`); with `wait_clear`
        the move waits for that drone to move away instead."""
        goal = move_goal("move", forward, backward, right, left, up, down, to, lat, lon)
        # Where the drone is now matters only to a relative move or one that keeps its
        # heading; an absolute one with a yaw goes at once (no wait for telemetry).
        base = handle(d).plan_base() if isinstance(goal, tuple) or yaw is None else None
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
        self._send(d, body, wait_clear=bool(wait_clear))
        handle(d).anchor = Position(goal.lat, goal.lon, goal.alt, heading)

    # ---- task bundles (SPEC §6) ------------------------------------------------------

    def push(self, d: Drone, steps: Any, on_link_loss: str = "continue", timeout: Duration = DEFAULT_BUNDLE_TIMEOUT_S,
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
            body["until"] = as_guard(until)
        if sensed := sensor_guards(body):  # when the drone ends a step on them
            unknowable(self.m, f"{self._drone_id(d)}'s {' and '.join(sensed)} (a bundle's guard)")
        record = call(self.m, self.m.delivery.push(self._drone_id(d), body))
        handle(d).anchor = None
        call(self.m, self.m.next_telemetry(handle(d).live()))
        return record

    # ---- time and concurrency ------------------------------------------------------

    def sleep(self, duration: Duration) -> None:
        """Wait `duration` (seconds, or `3 * s`) on the mission's clock (simulated in fast time)."""
        call(self.m, self.m.clock.sleep(units.duration(duration, "sleep")))

    def run(self, fn: Callable[..., Any], *args: Any) -> Subroutine:
        """Start `fn(*args)` as a subroutine running beside the script (any verb too:
        `run(land, d)`); returns it at once, for `wait` and `stop`."""
        if not callable(fn):
            raise TypeError(f"run: expected a function, got {fn!r}")
        assert self.m.scheduler is not None
        return self.m.scheduler.spawn(fn, *args, name=getattr(fn, "__name__", None))

    def wait(self, *things: Any) -> None:
        """Wait for each thing: a subroutine to end, a drone's next telemetry, a field
        sensor's next reading (lists too)."""
        for thing in things:
            if isinstance(thing, Drone):
                call(self.m, self.m.next_telemetry(self._drone_id(thing)))
            elif isinstance(thing, Subroutine):
                if thing.running:
                    call(self.m, thing.ended())
            elif isinstance(thing, FieldSensor):
                unknowable(self.m, f"field sensor {thing.id}'s next reading")
                call(self.m, self.m.next_field_reading(thing.id))
            elif isinstance(thing, (list, tuple)):
                self.wait(*thing)
            else:
                raise TypeError(f"wait: expected drones, subroutines or field sensors, got {thing!r}")

    def field_sensors(self, type: str | None = None, near: Any = None, within: Any = None) -> list[FieldSensor]:  # noqa: A002
        """The field sensors heard (not on a drone; SPEC §2), nearest `near` first."""
        unknowable(self.m, "the field sensors heard" + (f" of type {type}" if type is not None else ""))
        return field_sensors_of(self.m.station.registry.field_readings(), type, near, within)

    def stop(self, *subs: Subroutine) -> None:
        """Stop these subroutines (started with `run`) and the commands they were waiting on."""
        assert self.m.scheduler is not None
        for sub in subs:
            if not isinstance(sub, Subroutine):
                raise TypeError(f"stop: expected a subroutine (from run), got {sub!r}")
            self.m.scheduler.stop(sub)

    # ---- plugins (mission/script/plugins.py) -------------------------------------------

    def enable(self, plugin_id: str, **inputs: Any) -> None:
        """Enable a loaded plugin for this mission with its inputs (typed, defaults apply)."""
        self.m.plugins.enable(plugin_id, inputs, self.base, self.namespace)

    def disable(self, plugin_id: str) -> None:
        """Disable a plugin enabled earlier in this mission."""
        self.m.plugins.disable(plugin_id, self.namespace)


def build_namespace(mission: ScriptHost, guards: Guards) -> dict[str, Any]:
    """The globals one mission script runs with."""
    verbs = Verbs(mission)
    base = common_names(guards)
    base.update({name: reported(mission, name, guarded(getattr(verbs, name))) for name in VERBS})
    base.update(channel=Channel(mission), mission_id=mission.id, step=Steps(), when=When(), relays=Relays(mission))
    verbs.base, verbs.namespace = base, dict(base)
    return verbs.namespace


def verb_signatures() -> dict[str, inspect.Signature]:
    """Each verb's signature as a script calls it (without `self`)."""
    signatures = {}
    for name in VERBS:
        sig = inspect.signature(getattr(Verbs, name))
        signatures[name] = sig.replace(parameters=list(sig.parameters.values())[1:])
    return signatures
