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
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from greenlet import getcurrent

from dronefleet.mission.lifecycle import assignment as a
from dronefleet.mission.lifecycle.runtime import Subroutine
from dronefleet.mission.script import units
from dronefleet.mission.script.activity import reported
from dronefleet.mission.script.channel import Channel
from dronefleet.mission.script.drone import COMPLETED, MIN_HANDOVER_HEIGHT_M, Drone, any_drone, call, guarded
from dronefleet.mission.script.field import FieldSensor, field_sensors_of
from dronefleet.mission.script.geo import Position
from dronefleet.mission.script.names import VERBS, common_names, near_place
from dronefleet.mission.script.relaying import Relays
from dronefleet.mission.script.sandbox import Guards
from dronefleet.mission.script.steps import Steps, When, altitude_body, as_guard, move_goal
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.geo import angle_diff_deg, normalize_deg

if TYPE_CHECKING:
    from dronefleet.mission.script.script import ScriptMission

DEFAULT_BUNDLE_TIMEOUT_S = 600.0  # push(timeout=…): how long a bundle may run before the drone gives up


def build_namespace(mission: ScriptMission, guards: Guards) -> dict[str, Any]:
    """The globals one mission script runs with."""
    m = mission
    clock = mission.clock

    def drone_id(d: Any) -> str:
        if not isinstance(d, Drone):
            raise TypeError(f"expected a drone (from assign), got {d!r}")
        return d._live()

    def send(d: Drone, body: dict[str, Any], wait: bool = True, wait_clear: bool = False) -> Any:
        target, generation = drone_id(d), d._gen
        status = call(m, m.execute(target, body, wait=wait, wait_clear=wait_clear))
        if wait and d._gen != generation and status.state not in COMPLETED:
            # `replace` swapped the drone while it ran this command (the return home
            # superseded it): the new drone, once in place, does it instead.
            target = drone_id(d)
            m.log("info", f"{target} takes over the interrupted {body['cmd']}")
            status = call(m, m.execute(target, body, wait=True))
        if wait:  # the wrapper then shows the effect (telemetry after completion)
            call(m, m.next_telemetry(d._live()))
        return status

    # ---- assignment ----------------------------------------------------------------

    def request_of(item: Any) -> a.Request:
        if isinstance(item, str):
            return a.ById(item)
        if item is any_drone or item is None:
            return a.AnyDrone()
        if isinstance(item, (a.ById, a.BySensors, a.Near, a.ByKind, a.ByRole, a.AnyRelay, a.AnyDrone, a.AllOf)):
            return item
        raise TypeError("assign: expected a drone id, any_drone, any_relay, with_sensors(…), near(…), of_kind(…) "
                        f"or with_role(…), got {item!r}")

    def assign(*items: Any, sensor: str | None = None, sensors: list[str] | None = None,
               near: Any = None, kind: str | None = None, role: str | None = None) -> Any:
        """Positional items ask for one drone each; the keywords together describe one
        drone more (`assign(sensor="gas", role="survey", near=pos)`: the nearest survey
        drone carrying gas)."""
        requests = [request_of(i) for i in items]
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
        drones = [Drone(m, i) for i in call(m, m.assign(requests))]
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
                call(m, m.take(new, request))
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
        send(d, altitude_body("takeoff", alt))
        d._anchor = None

    def land(d: Drone) -> None:
        send(d, {"cmd": "land"})
        d._anchor = None

    def home(d: Drone, alt: Any = None) -> None:
        send(d, altitude_body("return", alt))
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
            body["until"] = as_guard(until)
        record = call(m, m.push(drone_id(d), body))
        d._anchor = None
        call(m, m.next_telemetry(d._live()))
        return record

    # ---- time and concurrency ------------------------------------------------------

    def sleep(duration: Any) -> None:
        call(m, clock.sleep(units.duration(duration, "sleep")))

    def run(fn: Callable[..., Any], *args: Any) -> Subroutine:
        if not callable(fn):
            raise TypeError(f"run: expected a function, got {fn!r}")
        assert m.scheduler is not None
        return m.scheduler.spawn(fn, *args, name=getattr(fn, "__name__", None))

    def wait(*things: Any) -> None:
        for thing in things:
            if isinstance(thing, Drone):
                call(m, m.next_telemetry(drone_id(thing)))
            elif isinstance(thing, Subroutine):
                if thing.running:
                    call(m, asyncio.wait([thing._done]))
            elif isinstance(thing, FieldSensor):
                call(m, m.next_field_reading(thing.id))
            elif isinstance(thing, (list, tuple)):
                wait(*thing)
            else:
                raise TypeError(f"wait: expected drones, subroutines or field sensors, got {thing!r}")

    def field_sensors(type: str | None = None, near: Any = None, within: Any = None) -> list[FieldSensor]:  # noqa: A002
        """The field sensors heard (not on a drone; SPEC §2), nearest `near` first."""
        return field_sensors_of(m.station.registry.field_readings(), type, near, within)

    def stop(*subs: Subroutine) -> None:
        assert m.scheduler is not None
        for sub in subs:
            if not isinstance(sub, Subroutine):
                raise TypeError(f"stop: expected a subroutine (from run), got {sub!r}")
            m.scheduler.stop(sub)

    # ---- plugins (mission/script/plugins.py) -------------------------------------------

    def enable(plugin_id: str, **inputs: Any) -> None:
        """Enable a loaded plugin for this mission with its inputs (typed, defaults apply)."""
        m.plugins.enable(plugin_id, inputs, base, namespace)

    def disable(plugin_id: str) -> None:
        m.plugins.disable(plugin_id, namespace)

    defined = locals()
    verbs: dict[str, Any] = {name: reported(m, name, guarded(defined[name])) for name in VERBS}
    base = common_names(guards)  # what a plugin enabled by this mission sees
    base.update(verbs)
    base.update(channel=Channel(m), mission_id=m.id, step=Steps(), when=When(),
                relays=Relays(m))
    namespace = dict(base)  # the script's globals
    return namespace
