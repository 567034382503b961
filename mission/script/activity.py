"""What a mission's subroutines are doing, as the dashboard's lanes show it (`/events`
kind `subroutine`, `Mission.report`): each verb a script calls with the line of the
mission's script it was called from, and what `wait` and channel reads wait on."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from dronefleet.mission.lifecycle.greenlets import Subroutine, current_subroutine
from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.script.lines import script_line

QUIET = frozenset({"field_sensors"})  # verbs that only read: not worth a lane's update


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
