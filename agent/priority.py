"""Command priority (thesis §4.1.3, SPEC §2) as a pure decision table.

Given what the drone is doing and a new command, decide whether the new command
starts, waits for a takeoff to finish, or is refused — and which commands it ends.
No I/O, no clock: the handler feeds the situation in and applies the decision.

Rules:
- everything but `arm` and `return` is refused while disarmed (`return` always goes through);
- goto/move replace only a running goto/move, are queued while a takeoff runs (a newer
  queued one replaces the older), and are refused while landing or returning;
- arm and disarm end nothing (the flight controller refuses what is unsafe);
- any other command ends the running and the queued command.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from dronefleet.schemas.status import DISARMED, LANDING, RETURNING

GOTO_LIKE = frozenset({"goto", "move"})
INSTANT = frozenset({"arm", "disarm", "start_offboard", "stop_offboard", "cancel"})
CONTINUOUS_SETPOINTS = frozenset({"velocity_ned", "velocity_body", "attitude", "attitude_rate"})
SETPOINTS = CONTINUOUS_SETPOINTS | {"position_ned"}
ALWAYS_ALLOWED = frozenset({"arm", "return"})
REFUSED_WHILE = {"land": LANDING, "return": RETURNING}


@dataclass(frozen=True)
class Active:
    """A command the agent is executing (or holding in the queue)."""

    name: str
    command_id: str


@dataclass(frozen=True)
class Situation:
    armed: bool
    running: Active | None = None
    queued: Active | None = None


@dataclass(frozen=True)
class Decision:
    verdict: Literal["start", "queue", "refuse"]
    reason: str | None = None
    ends: tuple[Active, ...] = ()  # ended, in this order, before the new command acts


def decide(name: str, now: Situation) -> Decision:
    if not now.armed and name not in ALWAYS_ALLOWED:
        return Decision("refuse", DISARMED)
    running, queued = now.running, now.queued
    if name in GOTO_LIKE:
        if running is not None and running.name == "takeoff":
            return Decision("queue", ends=_present(queued))
        if running is not None and running.name in REFUSED_WHILE:
            return Decision("refuse", REFUSED_WHILE[running.name])
        return Decision("start", ends=_present(running, queued))
    if name in ("arm", "disarm"):
        return Decision("start")
    return Decision("start", ends=_present(running, queued))


def end_state(name: str) -> Literal["stop", "cancel"]:
    """How an ended command is reported: offboard streams `stop`, the rest `cancel`."""
    return "stop" if name in CONTINUOUS_SETPOINTS else "cancel"


def _present(*items: Active | None) -> tuple[Active, ...]:
    return tuple(i for i in items if i is not None)
