"""The flight-controller port: what the agent needs from any autopilot.

Adapters (the built-in simulated vehicle, MAVSDK for PX4) implement
`FlightController`; everything above it — priority, status tracking, telemetry —
is shared. Calls return when the autopilot accepted the command (not when it is
done) and raise FcRejected with the autopilot's reason otherwise. `state()` is the
latest snapshot, which may lag a command by up to one heartbeat on real hardware.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import msgspec

from dronefleet.schemas.errors import FleetError
from dronefleet.schemas.telemetry import Battery, GpsInfo, Home, Position, VelocityNed


class FcError(FleetError):
    """A flight-controller problem."""


class FcUnavailable(FcError):
    """The flight controller cannot be reached."""


class FcRejected(FcError):
    """The flight controller refused a command; the message is its reason."""


class FcState(msgspec.Struct, frozen=True, kw_only=True):
    connected: bool = False
    armed: bool = False
    flight_mode: str = "unknown"
    landed_state: str = "unknown"
    position: Position | None = None
    home: Home | None = None
    heading: float = 0.0
    velocity: VelocityNed = msgspec.field(default_factory=VelocityNed)
    battery: Battery | None = None
    gps_info: GpsInfo | None = None
    health_failures: tuple[str, ...] = ()
    local_ned: tuple[float, float, float] | None = None  # m from the autopilot's local origin


Listener = Callable[[FcState], None]


class Changes:
    """An adapter's listeners: each is called with every snapshot whose connection,
    arming, flight mode or landed state differs from the one offered before, in the
    order the adapter received them (`FlightController.watch`)."""

    def __init__(self) -> None:
        self._listeners: list[Listener] = []
        self._last: tuple[bool, bool, str, str] | None = None

    def watch(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def offer(self, state: FcState) -> None:
        key = (state.connected, state.armed, state.flight_mode, state.landed_state)
        if key == self._last:
            return
        self._last = key
        for listener in self._listeners:
            listener(state)


class FlightController(Protocol):
    async def start(self) -> None:
        """Connect; raise FcUnavailable when the autopilot does not answer in time."""

    @property
    def make(self) -> str | None:
        """The autopilot's make once connected: px4 or ardupilot; None for a simulated
        vehicle that is neither (the built-in simulator)."""

    def state(self) -> FcState: ...

    def watch(self, listener: Listener) -> None:
        """Call `listener` with the new snapshot at once whenever the connection,
        arming, flight mode or landed state changes: every edge, however short, in the
        order the autopilot reported them (a poll's phase could hide one)."""

    async def arm(self) -> None: ...

    async def disarm(self) -> None: ...

    async def takeoff(self, alt_m: float) -> None:
        """Climb to alt_m above ground."""

    async def land(self) -> None: ...

    async def goto(
        self, lat: float, lon: float, alt_amsl: float, yaw_deg: float | None, speed_mps: float | None
    ) -> None: ...

    async def return_to_launch(self, alt_m: float) -> None:
        """Climb to at least alt_m above home, fly home and land."""

    async def hold(self) -> None: ...

    async def start_offboard(self) -> None: ...

    async def stop_offboard(self) -> None: ...

    async def set_setpoint(self, kind: str, values: dict[str, float | None]) -> None:
        """Stream an offboard setpoint (position_ned, velocity_ned, velocity_body,
        attitude, attitude_rate); angles in degrees."""

    async def upload_fence(self, polygon: list[tuple[float, float]]) -> None:
        """Upload an inclusion polygon [(lat, lon), …] as the autopilot's geofence;
        raise FcError if it refuses or does not answer."""

    async def close(self) -> None: ...
