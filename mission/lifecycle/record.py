"""A mission's record and its causes (thesis tables 5.1-5.3, SPEC §4-§5): the wire
shapes a mission reports, what each cause of its end means, and the exceptions that
unwind a script when its mission ends or it breaks the sandbox."""

from __future__ import annotations

import traceback
from typing import Literal

import msgspec

from dronefleet.schemas.errors import FleetError

MissionStatus = Literal["pending", "running", "finished", "failed", "cancelled"]
# Thesis table 5.3, plus geofence, link_lost, ground_restart (SPEC §5), ground_lost (§14) and time_limit.
CAUSES: dict[str, tuple[MissionStatus, str]] = {
    "success": ("finished", "success"),
    "user": ("cancelled", "user request"),
    "manual": ("cancelled", "manual mode activated"),
    "return": ("cancelled", "automatic return to launch detected"),
    "requirements": ("failed", "not enough drones to fulfill mission requirements"),
    "cmd_exec": ("failed", "failure in command execution"),
    "cmd_parse": ("failed", "failure in command parsing"),
    "plugin_error": ("failed", "plugin encountered an error"),
    "plugin_param": ("failed", "illegal or missing plugin input parameter"),
    "plugin_missing": ("failed", "plugin is not loaded"),
    "plugin_disabled": ("failed", "plugin is not enabled"),
    "timeout": ("failed", "drone timeout"),
    "sensor": ("failed", "sensor timeout"),
    "script": ("failed", "malformed script"),
    "revoked": ("failed", "referenced revoked drone"),
    "drone_error": ("failed", "drone entered error state"),
    "security": ("failed", "mission script called a blacklisted method or import"),
    "irreplaceable": ("failed", "requested replacement of drone that can not be replaced"),
    "unexpected": ("failed", "unexpected exception"),
    "geofence": ("failed", "drone left the geofence"),
    "link_lost": ("failed", "lost the link to a drone"),
    "ground_restart": ("failed", "the ground station stopped while the mission ran"),
    "ground_lost": ("failed", "the ground running it was lost and its journal could not be taken over"),
    "time_limit": ("cancelled", "time limit reached"),  # fast-time simulation's --max-time
}


class MissionRecord(msgspec.Struct, kw_only=True):
    """SPEC §4 / thesis table 5.1."""

    mission_id: str
    name: str = ""
    status: MissionStatus = "pending"
    cause: str | None = None
    message: str | None = None
    start: int | None = None  # ms since the epoch
    end: int | None = None
    plugins: list[str] = msgspec.field(default_factory=list)
    active_drones: list[str] = msgspec.field(default_factory=list)
    used_drones: list[str] = msgspec.field(default_factory=list)
    submitted_by: str | None = None  # the API token's holder (SPEC §9), when tokens are on
    # A mission taken over from a lost ground runs as `<origin>-<id>`: the id its client
    # was given there, by which this ground finds it too (SPEC §14)
    submitted_as: str | None = None
    line: int | None = None  # the script's line its error ended it at (a plugin's errors name no line)


class MissionLogLine(msgspec.Struct, frozen=True, kw_only=True):
    timestamp: int
    level: Literal["info", "warn", "error"]
    message: str


class Activity(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """What one subroutine of a mission is doing (`/events` kind `subroutine`): it
    `started`, called a `verb` (at `line` of the mission's script), is `waiting` on
    something (a channel, a drone, another subroutine, a field sensor), or `ended`
    (`status` finished, failed or stopped). A plugin's subroutines carry `plugin`."""

    mission_id: str
    timestamp: int
    subroutine: str  # s0 is the script itself; s1, s2, … in the order they started
    name: str  # "main", the function `run` started, or the plugin's monitor
    event: Literal["started", "verb", "waiting", "ended"]
    parent: str | None = None  # the subroutine that started it
    plugin: str | None = None
    verb: str | None = None
    line: int | None = None  # in the mission's script; None inside a plugin's
    drones: list[str] = []
    waiting_on: str | None = None
    status: Literal["finished", "failed", "stopped"] | None = None


class CommandResult(msgspec.Struct, frozen=True, kw_only=True):
    """What one verb sent and how it ended, for the simulation result."""

    drone_id: str
    cmd: str
    t_sent_ms: int
    t_end_ms: int
    state: str
    target: dict[str, float] | None = None


class MissionOver(FleetError):
    """Internal: a verb found the mission failing; its subroutine unwinds."""


class SecurityViolation(BaseException):
    """Raised at run time; a BaseException so `except Exception` in a script cannot hide it."""


def mark_ended(record: MissionRecord, cause: str, message: str | None) -> tuple[Literal["info", "warn", "error"], str]:
    """Set the record's status, cause and message for `cause`; returns the log line that says so."""
    status, default = CAUSES[cause]
    record.status, record.cause, record.message = status, cause, message or default
    level: Literal["info", "warn", "error"] = "info" if status == "finished" else ("warn" if status == "cancelled" else "error")
    return level, f"Mission {status}: {cause}" + (f" - {message}" if message else "")


def script_frame(exc: BaseException) -> tuple[str, int | None]:
    """The file (`<mission m3>`, `<plugin x.py>`) and line of the innermost script frame."""
    found: tuple[str, int | None] = ("", None)
    for frame in traceback.extract_tb(exc.__traceback__):
        if frame.filename.startswith(("<mission", "<plugin")):
            found = (frame.filename, frame.lineno)
    return found


def script_line(exc: BaseException) -> int | None:
    return script_frame(exc)[1]
