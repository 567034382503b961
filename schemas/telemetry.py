"""Telemetry, sensor readings and link quality: what agents and sensors publish.

Shapes follow SPEC §2 (thesis table 4.7 plus velocity and a sequence number). Every
message carries `drone_id` and `timestamp` (ms since the Unix epoch). New fields must
get defaults so older receivers keep decoding newer senders.
"""

from __future__ import annotations

from typing import Any, Literal

import msgspec

FlightMode = Literal[
    "unknown", "ready", "takeoff", "hold", "mission", "return_to_launch", "land",
    "offboard", "follow_me", "manual", "altctl", "posctl", "acro", "stabilized", "rattitude",
]
FixType = Literal["no_gps", "no_fix", "fix_2d", "fix_3d", "fix_dgps", "rtk_float", "rtk_fixed"]
HealthCheck = Literal[
    "gyrometer", "accelerometer", "magnetometer", "level", "local_position",
    "global_position", "home_position",
]
LandedState = Literal["unknown", "on_ground", "in_air", "taking_off", "landing"]

# Modes in which a pilot with a radio is flying: the agent reports start/stop_manual
# on entering/leaving them, and the ground refuses commands meanwhile.
MANUAL_MODES: frozenset[str] = frozenset(
    {"manual", "altctl", "posctl", "acro", "stabilized", "rattitude"}
)


class _Msg(msgspec.Struct, frozen=True, kw_only=True):
    pass


class Battery(_Msg, frozen=True, kw_only=True):
    remaining_percent: float  # 0..1, as MAVSDK reports it despite the name
    voltage: float


class GpsInfo(_Msg, frozen=True, kw_only=True):
    satellites: int
    fix_type: FixType


class Home(_Msg, frozen=True, kw_only=True):
    lat: float
    lon: float
    alt: float  # m AMSL


class Position(_Msg, frozen=True, kw_only=True):
    lat: float
    lon: float
    alt: float  # m AMSL
    rel_alt: float = 0.0  # m above home


class VelocityNed(_Msg, frozen=True, kw_only=True):
    north: float = 0.0
    east: float = 0.0
    down: float = 0.0


class Telemetry(_Msg, frozen=True, kw_only=True):
    drone_id: str
    timestamp: int
    seq: int = 0
    armed: bool = False
    battery: Battery | None = None
    flight_mode: FlightMode = "unknown"
    gps_info: GpsInfo | None = None
    heading: float = 0.0
    health_failures: list[HealthCheck] = msgspec.field(default_factory=list)
    home: Home | None = None
    landed_state: LandedState = "unknown"
    position: Position | None = None
    velocity: VelocityNed = msgspec.field(default_factory=VelocityNed)
    speed: float = 0.0


class SensorReading(_Msg, frozen=True, kw_only=True):
    drone_id: str = ""
    timestamp: int
    type: str
    value: float | str | bool | list[float] | None = None  # optional when it has fields
    unit: str = ""
    fields: dict[str, float | str | bool | None] | None = None  # a sensor declared with fields (SPEC §2)
    sensor_id: str | None = None  # field sensors (not on a drone): on `sensor/<sensor_id>/<type>`
    position: Position | None = None  # field sensors: where they stand

    @property
    def data(self) -> Any:
        """What it read: its fields (a sensor declared with fields), else its value."""
        return self.fields if self.fields else self.value


GROUND_PEER = "ground"  # LinkQuality.peer of a drone's link to the ground


class LinkQuality(_Msg, frozen=True, kw_only=True):
    """Measured by the agent's probes on the real transport (SPEC §2, §8), never from distance."""

    drone_id: str
    timestamp: int
    peer: str = GROUND_PEER  # GROUND_PEER or another drone's id
    rtt_ms: float | None = None  # mean over the answered probes of the window
    jitter_ms: float | None = None  # mean change between consecutive RTTs
    loss: float = 0.0  # 0..1: probes unanswered over the last window
    quality: float = 0.0  # 0..1 score from loss and rtt
    hops: int | None = None  # mesh hops to the peer when known
