"""The port through which missions reach the fleet (and the only one).

Missions read what the ground knows (`registry`), hear what happens (`listen`), claim
and free drones, send commands and write ground log lines — nothing else. The ground's
`GroundStation` implements this protocol, and `GroundPort`, the mission manager's wider
one; the composition root (`dronefleet.compose`) hands it to the mission manager. Mission code therefore never imports `ground/`, and a test
or another runtime can stand in for the ground with anything of this shape.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from dronefleet.schemas.bundles import BundleRecord, BundleReply
from dronefleet.schemas.commands import CommandReply
from dronefleet.schemas.config_loading import MissionSettings
from dronefleet.schemas.fleet import DroneInfo, WatchEvent
from dronefleet.schemas.status import CommandStatus
from dronefleet.schemas.telemetry import SensorReading, Telemetry


class FleetView(Protocol):
    """What the ground knows now of every registered drone."""

    def __contains__(self, drone_id: str) -> bool: ...
    def ids(self) -> list[str]: ...
    def info(self, drone_id: str) -> DroneInfo: ...
    def telemetry(self, drone_id: str) -> Telemetry: ...
    def sensor_readings(self, drone_id: str) -> list[SensorReading]: ...
    def field_readings(self) -> list[SensorReading]:
        """The latest reading of every field sensor (not on a drone) and type, with its
        `sensor_id` and `position` (SPEC §2)."""
        ...
    @property
    def relays(self) -> frozenset[str] | None:
        """On a secured mesh, the drones it lets carry others' traffic (SPEC §9); None: all."""
        ...


class MissionConfig(Protocol):
    @property
    def mission(self) -> MissionSettings: ...


class FleetPort(Protocol):
    @property
    def config(self) -> MissionConfig: ...

    @property
    def registry(self) -> FleetView: ...

    def listen(self, listener: Callable[[WatchEvent], None]) -> Callable[[], None]:
        """Call `listener` synchronously with every telemetry, status and drone change;
        returns the function that stops it."""
        ...

    async def assign(self, drone_id: str, mission_id: str) -> None:
        """Claim a drone for a mission; raises CommandRejected (409) if another holds it."""
        ...

    def release(self, drone_id: str) -> None: ...

    async def command(self, drone_id: str, body: bytes, mission_id: str | None = None) -> CommandReply:
        """Send one command (SPEC §2 JSON) as mission `mission_id`; raises
        CommandRejected (404/409), InvalidMessage (400) or bus Unreachable (504)."""
        ...

    async def push(self, drone_id: str, body: bytes, mission_id: str | None = None) -> BundleReply:
        """Send one task bundle (SPEC §6 JSON); raises as `command`."""
        ...

    async def bundle_record(self, drone_id: str, bundle_id: str) -> BundleRecord:
        """The agent's record of a bundle; raises CommandRejected or Unreachable."""
        ...

    def log_ground(self, level: str, message: str) -> None: ...
    def new_command_id(self) -> str:
        """A fresh command id (seeded in fast time, so a run replays to the byte)."""
        ...


class GroundView(FleetView, Protocol):
    """The ground's own view: also the command statuses it kept. A mission reads a
    command's outcome from its reply and the events it hears, never from this history."""

    def command_statuses(self, drone_id: str) -> list[CommandStatus]:
        """Its latest command statuses, oldest first."""
        ...


class GroundPort(FleetPort, Protocol):
    """What the mission manager, on the ground, uses besides what its missions do: the
    statuses history (to catch a resumed mission up) and the watchers' fan-out (every
    mission record, log line and activity). A mission's own process has neither."""

    @property
    def registry(self) -> GroundView: ...

    def broadcast(self, event: WatchEvent) -> None: ...
