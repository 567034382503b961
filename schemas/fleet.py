"""What the ground knows about a drone, as the ground and the missions share it.

The registry (ground/) derives these; missions (mission/) read them through their
port. Plain data, no I/O: the one vocabulary both sides import from below.
"""

from __future__ import annotations

from typing import Any, Literal, get_args

import msgspec

from dronefleet.schemas.about import SensorDeclaration
from dronefleet.schemas.status import Coords
from dronefleet.schemas.telemetry import LinkQuality

# unreachable: heard, but no route from the ground to its command queryable (issue 76)
DroneState = Literal["unknown", "error", "manual", "unreachable", "active", "hold", "ready"]
DRONE_STATES: tuple[str, ...] = get_args(DroneState)

CRITICAL_BATTERY = "Critical battery level"
LOW_BATTERY = "Low battery level"
FC_DISCONNECTED = "Flight controller disconnected"
HEALTH_PREFIX = "Failed health check"
HEALTH_FAILING = "Health check failing"  # the warning before health_error_after_s
LINK_DEGRADED = "Link degraded"
LINK_LOST = "Link lost"
LINK_RESTORED = "Link restored"
COMMANDS_UNREACHABLE = "Commands cannot reach it"
COMMANDS_REACH = "Commands reach it again"


class CurrentCommand(msgspec.Struct, frozen=True, kw_only=True):
    description: str
    timestamp: int  # ms since the epoch, when it started (ground clock)
    command: str
    command_id: str
    coords: Coords | None = None  # goto/move: the target
    altitude: float | None = None  # takeoff/return: the altitude it climbs to


class BundleInfo(msgspec.Struct, frozen=True, kw_only=True):
    """The task bundle a drone is running (SPEC §6), as the ground last heard of it."""

    bundle_id: str
    step: int  # index of the current step
    steps: int
    description: str  # the current step, e.g. "Go to 40.633700, -8.660500"


class DroneInfo(msgspec.Struct, frozen=True, kw_only=True):
    drone_id: str
    state: DroneState
    current_command: CurrentCommand | None
    sensors: list[str]
    mission: str | None
    errors: list[str]
    warns: list[str]
    link: LinkQuality | None = None  # the drone's measured link to the ground
    bundle: BundleInfo | None = None  # the task bundle it is running
    # What it says it is (SPEC §2 About); None until the ground has heard it.
    kind: str | None = None
    roles: list[str] | None = None
    sensors_declared: list[SensorDeclaration] | None = None
    autopilot: str | None = None  # its flight controller's make: px4, ardupilot (None: not said, or simulated)


class WatchEvent(msgspec.Struct, frozen=True):
    """One thing that happened, as the ground hands it to watchers and missions."""

    kind: str  # telemetry | status | drone | sensor (missions only) | log | mission | mission_log | end
    data: Any
    id: int | None = None  # log lines: their row id in the event log
