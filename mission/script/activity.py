"""What a mission's subroutines are doing, as the dashboard's lanes show it (`/events`
kind `subroutine`, `Mission.report`): each verb a script calls with the line of the
mission's script it was called from, and what `wait` and channel reads wait on."""

from __future__ import annotations

import sys
from collections.abc import Callable
from types import FrameType
from typing import Any

from dronefleet.mission.lifecycle.greenlets import Subroutine, current_subroutine
from dronefleet.mission.lifecycle.mission import Mission

QUIET = frozenset({"field_sensors"})  # verbs that only read: not worth a lane's update


def script_line(mission: Mission) -> int | None:
    """The line of the mission's own script the running verb was called from (the
    innermost frame compiled from it); None when only a plugin's code is on the stack."""
    code = getattr(mission, "code", None)
    filename = getattr(code, "co_filename", None)
    # The verb's caller and outward. Not sys._getframe(2): a verb handed to `run` as a
    # subroutine (`run(land, d)`) starts a greenlet's stack with no frame above it,
    # and _getframe raised "call stack is not deep enough".
    frame: FrameType | None = sys._getframe(1).f_back
    while frame is not None:
        if frame.f_code.co_filename == filename:
            return frame.f_lineno
        frame = frame.f_back
    return None


def describe(thing: Any) -> str:
    """What `wait(thing)` waits on, in words."""
    from dronefleet.mission.script.drone import Drone
    from dronefleet.mission.script.field_sensors import FieldSensor

    if isinstance(thing, Drone):
        return f"drone {thing.id}"
    if isinstance(thing, Subroutine):
        return f"subroutine {thing.name} ({thing.sid})"
    if isinstance(thing, FieldSensor):
        return f"field sensor {thing.id}"
    if isinstance(thing, (list, tuple)):
        return ", ".join(describe(t) for t in thing)
    return type(thing).__name__


def reported(mission: Mission, name: str, verb: Callable[..., Any]) -> Callable[..., Any]:
    """`verb` telling the mission what its subroutine is doing before it runs."""
    from dronefleet.mission.script.drone import Drone

    if name in QUIET:
        return verb

    def call(*args: Any, **kwargs: Any) -> Any:
        # the drones it acts on (those `run` hands to a new subroutine are that one's)
        drones = [] if name == "run" else [a.id for a in (*args, *kwargs.values()) if isinstance(a, Drone)]
        if name == "wait":
            mission.report(current_subroutine(), "waiting", name, line=script_line(mission), drones=drones,
                           waiting_on=describe(args))
        else:
            mission.report(current_subroutine(), "verb", name, line=script_line(mission), drones=drones)
        return verb(*args, **kwargs)

    call.__name__ = verb.__name__
    call.__doc__ = verb.__doc__
    return call


def waiting_on_channel(mission: Mission, name: str) -> None:
    mission.report(current_subroutine(), "waiting", "channel", line=script_line(mission), waiting_on=f"channel.{name}")
