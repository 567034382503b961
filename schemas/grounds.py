"""What grounds say of themselves on a mesh they share (SPEC §14): `ground/<id>/info`
and, from the active one, `ground/<id>/active` with its epoch, which agents fence on."""

from __future__ import annotations

from typing import Literal

import msgspec

from dronefleet.schemas.errors import CommandRejected

GroundRole = Literal["ground", "observer"]
STALE_GROUND = "stale_ground"  # an agent's refusal of a command or bundle from an older epoch than it heard
RESERVED = frozenset({"alive", "ping"})  # `ground/alive`, `ground/ping` are keys of their own: not ground ids


class GroundInfo(msgspec.Struct, frozen=True, kw_only=True):
    """What a ground says of itself (queryable `ground/<id>/info`)."""

    ground_id: str
    priority: int = 0
    role: GroundRole = "ground"
    http: str = ""  # where its API answers, for a standby's 503 to point at
    epoch_seen: int = 0  # the highest epoch it has heard or held: a ground taking over goes above it
    epoch_held: int = 0  # the highest epoch it held itself: one holding ours too makes ours ambiguous


class StandbyError(msgspec.Struct, frozen=True, kw_only=True):
    """What a ground that does not command answers a command, a push or a mission
    submission: `standby` (503) or `observer` (403, it never commands), naming the
    active ground and where its API answers ("" while none is or it is unknown)."""

    error: Literal["standby", "observer"] = "standby"
    active: str
    http: str

    @property
    def status(self) -> int:
        return 403 if self.error == "observer" else 503


class NotCommanding(CommandRejected):
    """This ground does not command now (SPEC §14): what it refuses, whoever asks
    (drone commands, pushes, mission submission and cancellation), says so by this."""

    def __init__(self, refusal: StandbyError) -> None:
        role = "an observer" if refusal.error == "observer" else "standby"
        super().__init__(refusal.status, f"this ground is {role}: {refusal.active or 'no ground'} is active"
                         + (f" ({refusal.http})" if refusal.http else ""), code=refusal.error)
        self.refusal = refusal


class GroundLogLine(msgspec.Struct, frozen=True, kw_only=True):
    """One line of a ground's event log on `ground/<id>/log`, numbered as in that log."""

    seq: int
    timestamp: int
    level: str
    drone_id: str | None = None
    message: str


class GroundMissionChange(msgspec.Struct, frozen=True, kw_only=True):
    """One change to a ground's missions on `ground/<id>/missions`, numbered: a mission
    record as it now is (`record`) or a line of its log (`line`), as JSON text."""

    seq: int
    mission_id: str
    kind: str
    body: str


class ActiveGround(msgspec.Struct, frozen=True, kw_only=True):
    """Published on `ground/<id>/active` by the active ground (and answered to a query)."""

    ground_id: str
    epoch: int
    timestamp: int
    streams: dict[str, int] = {}  # where each numbered record ends ("log", "missions"): a copy behind catches up
