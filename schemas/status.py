"""Status events an agent publishes on `drone/<id>/status` (thesis tables 4.5, 4.6).

Two shapes share the key: CommandStatus (has `command`) follows one command through
its life, SystemStatus (has `component`) reports events nobody asked for.
"""

from __future__ import annotations

from typing import Literal

import msgspec

from dronefleet.schemas.telemetry import Position

FAILSAFE_ID_PREFIX = "failsafe-"  # command ids of what an agent sends itself when it loses the ground
FAILSAFE_REASON = "lost-link failsafe"  # starts the reason of a command its failsafe ended
GEOFENCE_OUTSIDE = "outside the geofence"  # a failsafe's reason after "return: " (SPEC §11)
RETURNING = "returning"  # why a goto is refused while a return (the failsafe's too) runs
LANDING = "landing"  # why a goto is refused while a landing (the failsafe's too) runs
DISARMED = "disarmed"  # why a command is refused by a disarmed drone, or ended when it disarms



def ended_by_failsafe(status: CommandStatus) -> bool:
    """Did the agent's own lost-link failsafe (not the ground) end this command?"""
    return status.state == "cancel" and (status.reason or "").startswith(FAILSAFE_REASON)


TERMINAL_STATES = frozenset({"finish", "success", "failure", "cancel", "stop"})  # a command's last status
CommandState = Literal["start", "stop", "cancel", "finish", "queued", "success", "failure"]
SystemState = Literal[
    "connect", "disconnect", "disarm", "return", "stop_offboard", "start_manual",
    "stop_manual", "link_lost", "link_restored", "failsafe",
]


class Coords(msgspec.Struct, frozen=True, kw_only=True):
    lat: float
    lon: float
    alt: float  # m AMSL


class CommandStatus(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    drone_id: str
    timestamp: int
    command_id: str = ""
    command: str
    state: CommandState
    reason: str | None = None  # failures (and cancels) say why
    altitude: float | None = None  # takeoff / return starts: m above ground / home
    coords: Coords | None = None  # goto / move starts: the target


class SystemStatus(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    drone_id: str
    timestamp: int
    component: str  # "system" for autopilot events
    state: SystemState
    reason: str | None = None


Status = CommandStatus | SystemStatus

__all__ = ["CommandState", "CommandStatus", "Coords", "Position", "Status", "SystemState", "SystemStatus"]
