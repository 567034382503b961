"""The built-in simulated flight controller (`--fc sim`): the sim/ vehicle model
behind the flight-controller port, stepped in the agent's clock.

It behaves towards the agent as the MAVSDK adapter does: commands are accepted or
refused with the vehicle's reason, offboard setpoints are re-sent at 20 Hz (as
MAVSDK streams them) until offboard stops, and a pulled link shows as
`connected=False` with the last values kept.

URL: `sim` or `sim://?lat=40.63&lon=-8.66&alt=8.2` for the spawn point; add
`control=PORT` to accept faults (`fleet fault --control 127.0.0.1:PORT …`, e.g. an
RC takeover) on a UDP control channel, as `fleet sim` does, and PX4 parameters that
tune the vehicle (`MPC_LAND_SPEED=1.2`, as `fleet sim --param`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from urllib.parse import parse_qs, urlsplit

import msgspec

from dronefleet.agent.fc_port import Changes, FcRejected, FcState, Listener
from dronefleet.bus.clock import Clock, until_next_tick_s
from dronefleet.schemas.errors import ConfigError
from dronefleet.sim import autopilot_params
from dronefleet.sim.faults import FaultChannel, open_fault_channel
from dronefleet.sim.vehicle import Vehicle

DEFAULT_SPAWN = (40.633490, -8.660815, 8.2)  # thesis test field, Aveiro
STEP_S = 0.02
# A vehicle at rest (disarmed on the ground, no setpoint streaming) is stepped this often:
# nothing moves, commands refresh the state at once (`_command`), and what the fault
# channel changes shows within a step. An idle agent's loop woke 50 times a second for it
# (ADR 0003 "What it costs").
REST_STEP_S = 0.25
SETPOINT_PERIOD_S = 0.05
FENCE_MAX_VERTICES = 64  # PX4 v1.16 keeps at most this many fence items (DM_KEY_FENCE_POINTS_MAX)


def parse_sim_url(url: str) -> tuple[Vehicle, int | None]:
    """The vehicle a sim URL describes, and its fault-control port if any."""
    parts = urlsplit(url)
    if url != "sim" and parts.scheme != "sim":
        raise ConfigError(f"not a sim URL: {url!r}")
    query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
    unknown = set(query) - {"lat", "lon", "alt", "control"} - set(autopilot_params.PX4)
    if unknown:
        raise ConfigError(f"fc {url!r}: unknown parameter(s) {', '.join(sorted(unknown))} "
                          f"(known: lat, lon, alt, control, {', '.join(sorted(autopilot_params.PX4))})")
    try:
        lat, lon, alt = (float(query.get(k, d)) for k, d in zip(("lat", "lon", "alt"), DEFAULT_SPAWN, strict=True))
        control = int(query["control"]) if "control" in query else None
        vehicle = Vehicle(lat, lon, alt)
        for name in sorted(set(query) & set(autopilot_params.PX4)):
            autopilot_params.tune(vehicle, autopilot_params.PX4, name, float(query[name]))
    except ValueError as exc:
        raise ConfigError(f"fc {url!r}: {exc}") from None
    return vehicle, control


class SimFlightController:
    def __init__(self, vehicle: Vehicle, clock: Clock, control_port: int | None = None) -> None:
        self.vehicle = vehicle
        self._control_port = control_port
        self._control: asyncio.BaseTransport | None = None
        self._clock = clock
        self._task: asyncio.Task[None] | None = None
        self._setpoint: tuple[str, dict[str, float | None]] | None = None
        self._last_sent = 0.0
        self._snapshot = FcState()
        self._changes = Changes()

    make = None  # the built-in simulator: a vehicle of its own, neither make

    def watch(self, listener: Listener) -> None:
        self._changes.watch(listener)

    def _refresh(self) -> None:
        self._snapshot = self._read()
        self._changes.offer(self._snapshot)

    async def start(self) -> None:
        self._refresh()
        if self._control_port is not None:
            try:
                self._control = await open_fault_channel(self._control_port, FaultChannel(
                    lambda name: self.vehicle,
                    lambda: {"vehicle": f"{self.vehicle.mode} {self.vehicle.landed_state} battery {self.vehicle.battery:.0%}"},
                ))
            except OSError as exc:
                raise ConfigError(f"sim fault control port {self._control_port}: {exc.strerror}") from None
        self._task = asyncio.get_running_loop().create_task(self._run(), name="sim vehicle")

    async def _run(self) -> None:
        last = self._clock.monotonic()
        while True:
            v = self.vehicle
            period_s = REST_STEP_S if not v.armed and v.landed_state == "on_ground" and self._setpoint is None else STEP_S
            await self._clock.sleep(until_next_tick_s(self._clock.monotonic(), period_s))
            now = self._clock.monotonic()
            if self._setpoint and now - self._last_sent >= SETPOINT_PERIOD_S:
                self._send_setpoint(now)
            self.vehicle.step(now - last)
            last = now
            if self._setpoint and self.vehicle.mode != "offboard" and now - self._last_sent > 3.0:
                self._setpoint = None  # MAVSDK gives up streaming when offboard never shows
            self._refresh()
            self.vehicle.events.clear()

    def _send_setpoint(self, now: float) -> None:
        assert self._setpoint is not None
        kind, values = self._setpoint
        if self.vehicle.connected:
            self.vehicle.set_setpoint(kind, **values)
        self._last_sent = now

    def _read(self) -> FcState:
        v = self.vehicle
        if not v.connected:
            return msgspec.structs.replace(self._snapshot, connected=False)
        return FcState(
            connected=True,
            armed=v.armed,
            flight_mode=v.mode,
            landed_state=v.landed_state,
            position=v.position(),
            home=v.home,
            heading=v.heading,
            velocity=v.velocity(),
            battery=v.battery_state(),
            gps_info=v.gps(),
            health_failures=tuple(sorted(v.health_failures)),
            local_ned=v.local_ned(),
        )

    def state(self) -> FcState:
        return self._snapshot

    def _command(self, call: Callable[..., str | None], *args: object, ends_stream: bool = False) -> None:
        """Run one vehicle command: refused when the link is pulled or the vehicle says no."""
        if not self.vehicle.connected:
            raise FcRejected("flight controller not responding")
        if ends_stream:
            self._setpoint = None
        result = call(*args)
        if result is not None:
            raise FcRejected(result)
        self._refresh()

    async def arm(self) -> None:
        self._command(self.vehicle.arm)

    async def disarm(self) -> None:
        self._command(self.vehicle.disarm)

    async def takeoff(self, alt_m: float) -> None:
        self._command(self.vehicle.takeoff, alt_m)

    async def land(self) -> None:
        self._command(self.vehicle.land, ends_stream=True)

    async def goto(
        self, lat: float, lon: float, alt_amsl: float, yaw_deg: float | None, speed_mps: float | None
    ) -> None:
        self._command(self.vehicle.goto, lat, lon, alt_amsl, yaw_deg, speed_mps, ends_stream=True)

    async def return_to_launch(self, alt_m: float) -> None:
        self._command(self.vehicle.return_to_launch, alt_m, ends_stream=True)

    async def hold(self) -> None:
        self._command(self.vehicle.hold, ends_stream=True)

    async def set_setpoint(self, kind: str, values: dict[str, float | None]) -> None:
        if not self.vehicle.connected:
            raise FcRejected("flight controller not responding")
        # Numbers only, as MAVSDK's setpoint structs take them (fc_mavsdk.py): a field that
        # is no setpoint value fails here as it fails there.
        self._setpoint = (kind, {k: 0.0 if v is None else float(v) for k, v in values.items()})
        self._send_setpoint(self._clock.monotonic())

    async def start_offboard(self) -> None:
        self._command(self.vehicle.start_offboard)

    async def stop_offboard(self) -> None:
        self._command(self.vehicle.stop_offboard, ends_stream=True)

    async def upload_fence(self, polygon: list[tuple[float, float]]) -> None:
        """Store the polygon on the vehicle (`vehicle.fence`) as PX4 takes it through
        MAVSDK: at 1e-7° resolution; refused with MAVSDK's results for what MAVSDK
        checks itself (under three vertices, coordinates out of range) and for more
        vertices than PX4 stores (it answers MAV_MISSION_NO_SPACE)."""
        if not self.vehicle.connected:
            raise FcRejected("fence: flight controller not responding")
        if len(polygon) < 3 or not all(-90 <= lat <= 90 and -180 <= lon <= 180 for lat, lon in polygon):
            raise FcRejected("fence: invalid argument")
        if len(polygon) > FENCE_MAX_VERTICES:
            raise FcRejected("fence: too many geofence items")
        self.vehicle.fence = [(round(lat * 1e7) / 1e7, round(lon * 1e7) / 1e7) for lat, lon in polygon]

    async def close(self) -> None:
        if self._control is not None:
            self._control.close()
        if self._task is not None:
            self._task.cancel()
            await asyncio.wait([self._task])

