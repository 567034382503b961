"""SPEC §11 at the ground: where each drone is about to fly, and the checks a command
passes before it goes — the fence, then the other drones' targets and hovering spots.

Kept beside the station (ground/station.py), which owns the mesh: this is the ground's
own memory of what it sent, with no I/O.
"""

from __future__ import annotations

import math

from dronefleet.ground.config import GroundConfig
from dronefleet.ground.registry import Registry
from dronefleet.schemas.commands import Command
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.fence import CONFLICT, flight_of
from dronefleet.schemas.fence import REASON as FENCE
from dronefleet.schemas.geo import distance_m
from dronefleet.schemas.status import TERMINAL_STATES, CommandStatus

Spot = tuple[float, float, float]  # lat, lon, alt AMSL


class Airspace:
    def __init__(self, config: GroundConfig, registry: Registry) -> None:
        self.config = config
        self.registry = registry
        # drone → (command id, lat, lon, alt AMSL): where a command this ground sent takes
        # it, from the moment it passed the checks until it ends (its `start` comes later)
        self._claims: dict[str, tuple[str, float, float, float]] = {}

    def check(self, drone_id: str, command: Command) -> Spot | CommandRejected | None:
        """Where the command takes the drone (lat, lon, alt AMSL) if known, None if it
        goes nowhere, or why it is refused: 409 geofence, or 409 conflict naming the other drone."""
        telem, fence = self.registry.telemetry(drone_id), self.config.geofence
        flight = flight_of(command, telem.position, telem.heading)
        if flight is None:
            return None
        why = fence.check(flight.start, flight.end, flight.alt) if fence.limits else None
        if why is not None:
            return CommandRejected(409, why, code=FENCE)
        if flight.alt is None or telem.position is None:
            return None
        spot = (*flight.end, telem.position.alt - telem.position.rel_alt + flight.alt)
        clash = self._nearest_claim(drone_id, spot)
        if clash is not None and clash[1] < fence.min_separation_m:
            other, gap, what = clash
            why = (f"{CONFLICT}: the target is {gap:.1f} m from {what} of {other} "
                   f"(geofence.min_separation_m {fence.min_separation_m:g})")
            return CommandRejected(409, why, code=CONFLICT, other=other)
        return spot

    def sent(self, drone_id: str, command: Command, spot: Spot | None) -> None:
        """A command that passed the checks is on its way: it claims its target, or (land,
        return, cancel…) gives up the drone's claim."""
        if spot is not None:
            self._claims[drone_id] = (command.command_id, *spot)
        elif command.name not in ("arm", "disarm"):
            self._claims.pop(drone_id, None)

    def undo(self, drone_id: str, command_id: str) -> None:
        """The command never got through: its claim goes."""
        if self._claims.get(drone_id, ("",))[0] == command_id:
            del self._claims[drone_id]

    def on_status(self, status: CommandStatus) -> None:
        if status.state in TERMINAL_STATES:
            self.undo(status.drone_id, status.command_id)  # it hovers there now (or wherever it stopped)

    def _nearest_claim(self, drone_id: str, target: Spot) -> tuple[str, float, str] | None:
        """The other drone whose claim on the air is nearest `target` (lat, lon, alt
        AMSL), 3-D: where the command this ground sent it, its running goto/move or its
        takeoff goes, or else where it hovers; (drone, metres, what)."""
        nearest: tuple[str, float, str] | None = None
        for other in self.registry.ids():
            if other == drone_id or self.registry.info(other).state == "unknown":
                continue
            for spot, what in self._claims_of(other):
                gap = math.hypot(distance_m(target[0], target[1], spot[0], spot[1]), target[2] - spot[2])
                if nearest is None or gap < nearest[1]:
                    nearest = (other, gap, what)
        return nearest

    def _claims_of(self, drone_id: str) -> list[tuple[Spot, str]]:
        info, t = self.registry.info(drone_id), self.registry.telemetry(drone_id)
        cmd, pos = info.current_command, t.position
        spots: list[tuple[Spot, str]] = []
        sent = self._claims.get(drone_id)
        if sent is not None:
            spots.append((sent[1:], "the target"))
        if cmd is not None and cmd.coords is not None:
            spots.append(((cmd.coords.lat, cmd.coords.lon, cmd.coords.alt), "the target"))
        elif cmd is not None and cmd.command == "takeoff" and cmd.altitude is not None and pos is not None:
            spots.append(((pos.lat, pos.lon, pos.alt - pos.rel_alt + cmd.altitude), "the takeoff"))
        elif not spots and cmd is None and pos is not None and t.armed and t.landed_state == "in_air":
            spots.append(((pos.lat, pos.lon, pos.alt), "the hovering spot"))
        return spots
