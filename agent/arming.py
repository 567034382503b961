"""The agent's one view of "armed": the autopilot's reported arming as a sequence of
edges, and the arm or disarm the agent asked for that the reports do not show yet.

The reported flag comes from the autopilot's heartbeat, up to a second behind (PX4
reports `armed` about 1 s after an accepted arm). So an accepted arm or disarm is
*expected* until the report shows it, or `EFFECT_LAG_S` passes. The first reported
edge after the request settles it: the edge the request asked for is its effect; any
other edge is the autopilot's own (a landing's auto-disarm after an arm that found the
drone still armed) and overrides the request. Nothing here polls: the handler feeds
every reported value in the order the autopilot sent it (ADR 0018).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

# How long an accepted command's effects may take to show in telemetry (one heartbeat
# on PX4, plus margin): within it, those effects are not "system" events.
EFFECT_LAG_S = 3.0

Edge = Literal["requested", "unrequested"]


@dataclass
class Request:
    command_id: str
    armed: bool
    until_s: float  # past this, a report that never showed it has the last word


@dataclass
class Arming:
    reported: bool = False
    pending: list[Request] = field(default_factory=list)  # accepted arms and disarms not reported yet, oldest first

    def requested(self, command_id: str, armed: bool, now_s: float) -> None:
        """An arm (True) or disarm was accepted: expect the report to follow, unless it
        already says so and nothing else is pending (an arm of an armed drone changes
        nothing at the autopilot)."""
        if armed != self.reported or self.pending:
            self.pending.append(Request(command_id, armed, now_s + EFFECT_LAG_S))

    def acknowledged(self, command_id: str, now_s: float) -> None:
        """The autopilot acknowledged the request (an arm may first wait on a mode
        change): the lag its report may take counts from now."""
        for request in self.pending:
            if request.command_id == command_id:
                request.until_s = now_s + EFFECT_LAG_S

    def refused(self, command_id: str) -> None:
        """The autopilot refused this arm or disarm: nothing to expect of it."""
        self.pending = [r for r in self.pending if r.command_id != command_id]

    def report(self, armed: bool, now_s: float) -> Edge | None:
        """A reported value: None if it is no edge; else whether the agent asked for it
        (within the lag allowed). The edge settles every request up to the one it shows."""
        if armed == self.reported:
            return None
        self.reported = armed
        live = [r for r in self.pending if now_s < r.until_s]
        shown = next((i for i, r in enumerate(live) if r.armed == armed), None)
        self.pending = [] if shown is None else live[shown + 1:]
        return "unrequested" if shown is None else "requested"

    def armed(self, now_s: float) -> bool:
        """What a decision takes as armed now: the newest request still expected, else
        the report."""
        live = [r for r in self.pending if now_s < r.until_s]
        return live[-1].armed if live else self.reported
