"""Commands an operator or mission sends to `drone/<id>/cmd`, and the agent's reply.

One tagged union keyed by `cmd` (SPEC §2 table): each command is its own frozen
Struct with exactly its required and optional fields, so decoding validates types,
ranges and presence in one pass and names the field at fault. `mode` may be given
and must then match the command's family.

Goto distinguishes a missing `yaw` (keep heading) from `yaw: null` (face the target)
with msgspec's UNSET.
"""

from __future__ import annotations

import json
import math
import re
import uuid
from typing import Annotated, ClassVar, Literal

import msgspec
from msgspec import UNSET, Meta, UnsetType

from dronefleet.schemas.auth import Auth
from dronefleet.schemas.errors import InvalidMessage

CommandMode = Literal["action", "offboard", "custom"]


def new_command_id() -> str:
    """A fresh command id: the ground's, a mission's and the agent's all come from here."""
    return str(uuid.uuid4())


# Ranges double as finiteness checks: NaN and infinities fail every bound.
Lat = Annotated[float, Meta(ge=-90.0, le=90.0, description="degrees")]
Lon = Annotated[float, Meta(ge=-180.0, le=180.0, description="degrees")]
AltAmsl = Annotated[float, Meta(ge=-500.0, le=10_000.0, description="m AMSL")]
AltAboveGround = Annotated[float, Meta(gt=0.0, le=1_000.0, description="m above ground")]
AltAboveHome = Annotated[float, Meta(ge=0.0, le=1_000.0, description="m above home")]
Speed = Annotated[float, Meta(gt=0.0, le=50.0, description="m/s")]
Angle = Annotated[float, Meta(ge=-360.0, le=360.0, description="degrees")]
AngleRate = Annotated[float, Meta(ge=-720.0, le=720.0, description="degrees/s")]
Metres = Annotated[float, Meta(ge=-10_000.0, le=10_000.0, description="m")]
Velocity = Annotated[float, Meta(ge=-50.0, le=50.0, description="m/s")]
Thrust = Annotated[float, Meta(ge=0.0, le=1.0, description="0..1")]


class _Command(msgspec.Struct, frozen=True, kw_only=True, tag_field="cmd", omit_defaults=True):
    MODE: ClassVar[str]
    drone_id: str = ""
    command_id: str = ""
    timestamp: int = 0
    mode: CommandMode | None = None
    auth: Auth | None = None  # the ground's signature (SPEC §9); absent on an unsecured fleet
    ground_epoch: Annotated[int, Meta(ge=0)] = 0  # SPEC §14: the sending ground's epoch (0: none, a direct client)
    ground_id: str = ""  # the sending ground: an epoch is held by the first ground an agent heard with it

    def __post_init__(self) -> None:
        if self.mode is not None and self.mode != self.MODE:
            raise ValueError(
                f"mode {self.mode!r} does not match this cmd (expected {self.MODE!r}) - at `$.mode`"
            )

    @property
    def name(self) -> str:
        return self.__struct_config__.tag  # type: ignore[return-value]


# What every command carries besides its own fields (who, which, when, whose ground):
# a setpoint's values are the rest.
COMMON_FIELDS = frozenset(_Command.__struct_fields__)


class Arm(_Command, tag="arm", frozen=True):
    MODE = "action"


class Disarm(_Command, tag="disarm", frozen=True):
    MODE = "action"


class Takeoff(_Command, tag="takeoff", frozen=True):
    MODE = "action"
    alt: AltAboveGround | None = None


class Land(_Command, tag="land", frozen=True):
    MODE = "action"


class Goto(_Command, tag="goto", frozen=True):
    MODE = "action"
    lat: Lat
    lon: Lon
    alt: AltAmsl | None = None
    yaw: Angle | None | UnsetType = UNSET
    speed: Speed | None = None


class Return(_Command, tag="return", frozen=True):
    MODE = "action"
    alt: AltAboveHome | None = None


class StartOffboard(_Command, tag="start_offboard", frozen=True):
    MODE = "offboard"


class StopOffboard(_Command, tag="stop_offboard", frozen=True):
    MODE = "offboard"


class PositionNed(_Command, tag="position_ned", frozen=True):
    MODE = "offboard"
    north: Metres = 0.0
    east: Metres = 0.0
    down: Metres = 0.0
    yaw: Angle | None = None  # None keeps the current heading


class VelocityNed(_Command, tag="velocity_ned", frozen=True):
    MODE = "offboard"
    north: Velocity = 0.0
    east: Velocity = 0.0
    down: Velocity = 0.0
    yaw: Angle | None = None


class VelocityBody(_Command, tag="velocity_body", frozen=True):
    MODE = "offboard"
    forward: Velocity = 0.0
    right: Velocity = 0.0
    down: Velocity = 0.0
    yaw: AngleRate = 0.0  # deg/s


class Attitude(_Command, tag="attitude", frozen=True):
    MODE = "offboard"
    roll: Angle = 0.0
    pitch: Angle = 0.0
    yaw: Angle = 0.0
    thrust: Thrust = 0.5


class AttitudeRate(_Command, tag="attitude_rate", frozen=True):
    MODE = "offboard"
    roll: AngleRate = 0.0
    pitch: AngleRate = 0.0
    yaw: AngleRate = 0.0
    thrust: Thrust = 0.5


class Cancel(_Command, tag="cancel", frozen=True):
    MODE = "custom"


class Turn(_Command, tag="turn", frozen=True):
    MODE = "custom"
    deg: Angle


class Move(_Command, tag="move", frozen=True):
    MODE = "custom"
    x: Metres = 0.0  # right
    y: Metres = 0.0  # forward
    z: Metres = 0.0  # up
    speed: Speed | None = None


Command = (
    Arm | Disarm | Takeoff | Land | Goto | Return | StartOffboard | StopOffboard
    | PositionNed | VelocityNed | VelocityBody | Attitude | AttitudeRate | Cancel | Turn | Move
)
COMMAND_TYPES: dict[str, type[_Command]] = {
    t.__struct_config__.tag: t for t in Command.__args__
}
# Metres above home at which an agent flies a return (`return`, the lost-link failsafe)
# unless its configuration says otherwise (agent config `return_altitude`).
DEFAULT_RETURN_ALT_M = 15.0
OFFBOARD_SETPOINTS = (PositionNed, VelocityNed, VelocityBody, Attitude, AttitudeRate)


class CommandReply(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    command_id: str
    accepted: bool
    reason: str | None = None
    ground_epoch: int | None = None  # with `stale_ground`: the newest ground epoch the agent heard (SPEC §14)


_decoder = msgspec.json.Decoder(Command)
_FIELD = re.compile(r" - at `(\$[^`]*)`")
_MISSING = re.compile(r"missing required field `([^`]+)`")


def decode_command(payload: bytes | str) -> Command:
    """Decode and validate one command; InvalidMessage names the field at fault."""
    try:
        return _decoder.decode(payload)
    except msgspec.ValidationError as exc:
        raise _invalid(exc) from None
    except msgspec.DecodeError:
        pass
    # Not strict JSON. Python's json accepts NaN/Infinity tokens, which senders built
    # on it emit; decode leniently so the range check can name the field instead of
    # answering "malformed".
    try:
        obj = json.loads(payload)
    except (ValueError, TypeError) as exc:
        raise InvalidMessage(f"malformed JSON: {exc}") from None
    if isinstance(obj, dict):
        for key, value in obj.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise InvalidMessage(f"{key}: must be a finite number, got {value}", field=f"$.{key}")
    try:
        return msgspec.convert(obj, Command)
    except msgspec.ValidationError as exc:
        raise _invalid(exc) from None


def _invalid(exc: msgspec.ValidationError) -> InvalidMessage:
    text = str(exc)
    match = _FIELD.search(text)
    field = match.group(1) if match else None
    reason = _FIELD.sub("", text)
    missing = _MISSING.search(reason)
    if missing and field in (None, "$"):
        field = f"$.{missing.group(1)}"
    if field == "$.cmd" and reason.startswith("Invalid value"):
        reason = f"unknown command {reason.removeprefix('Invalid value ')}; known: {', '.join(COMMAND_TYPES)}"
    if field:
        return InvalidMessage(f"{field.removeprefix('$.')}: {reason}", field=field)
    return InvalidMessage(reason)
