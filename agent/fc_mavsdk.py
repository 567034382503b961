"""The MAVSDK flight-controller adapter: PX4 (or any MAVLink autopilot) through
mavsdk 4.x, the native binding (libmavsdk in-process, no mavsdk_server).

Telemetry streams (`subscribe_*`) feed a cache that `state()` reads; commands go
through the Action and Offboard plugins and come back as FcRejected with MAVSDK's
result on refusal. Facts this relies on (shared/notes/mavsdk-facts.md): wait for
`is_connected()` (a HEARTBEAT) before commanding, or MAVSDK takes non-PX4 paths;
takeoff/RTL altitudes are parameter writes; `set_current_speed` replaces the
removed `set_maximum_speed`; serial URLs need a baud rate; `udp://host:port` means
outbound; heartbeat-driven fields lag a command by up to a second.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import AsyncIterator, Callable
from typing import Any
from urllib.parse import urlsplit

from dronefleet.agent.fc_port import FcRejected, FcState, FcUnavailable
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.geo import normalize_deg
from dronefleet.schemas.telemetry import Battery, GpsInfo, Home, Position, VelocityNed

log = logging.getLogger(__name__)

DEFAULT_BAUD = 57600
CONNECTED_POLL_S = 0.25
_HEALTH = {
    "is_gyrometer_calibration_ok": "gyrometer",
    "is_accelerometer_calibration_ok": "accelerometer",
    "is_magnetometer_calibration_ok": "magnetometer",
    "is_local_position_ok": "local_position",
    "is_global_position_ok": "global_position",
    "is_home_position_ok": "home_position",
}


def mavsdk_url(url: str) -> str:
    """Map the accepted `fc` forms onto MAVSDK 4.x connection URLs."""
    parts = urlsplit(url)
    scheme = parts.scheme
    if scheme == "udp":
        host = parts.hostname or ""
        if host in ("", "0.0.0.0") and parts.port:
            return f"udpin://0.0.0.0:{parts.port}"
        if parts.port:
            return f"udpout://{host}:{parts.port}"
    elif scheme in ("udpin", "udpout", "tcpin", "tcpout") and parts.port:
        return url
    elif scheme == "tcp" and parts.hostname and parts.port:
        return f"tcpout://{parts.hostname}:{parts.port}"
    elif scheme == "serial" and parts.path:
        device, _, baud = parts.path.partition(":")
        if baud and not baud.isdigit():
            raise ConfigError(f"fc {url!r}: baud rate {baud!r} is not a number")
        return f"serial://{device}:{baud or DEFAULT_BAUD}"
    raise ConfigError(
        f"fc {url!r}: expected sim, udp://:PORT, udpin://HOST:PORT, serial:///dev/DEVICE[:BAUD] or tcp://HOST:PORT"
    )


_mavsdk_log = logging.getLogger("mavsdk")
_forwarding = False


def _forward_mavsdk_log() -> None:
    """libmavsdk prints to stderr by default; route it through logging instead."""
    global _forwarding
    if _forwarding:
        return
    from mavsdk.logging import LogLevel, log_subscribe

    levels = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.DEBUG, LogLevel.WARN: logging.WARNING, LogLevel.ERROR: logging.ERROR}

    def forward(level: LogLevel, message: str, file: str | None, line: int) -> bool:
        _mavsdk_log.log(levels.get(level, logging.INFO), "%s", message)
        return True

    log_subscribe(forward)
    _forwarding = True


class MavsdkFlightController:
    def __init__(self, url: str, connect_timeout_s: float = 8.0) -> None:
        self.url = url
        self.mavsdk_url = mavsdk_url(url)
        self._timeout_s = connect_timeout_s
        self._sdk: Any = None
        self._system: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._cache: dict[str, Any] = {"connected": False}
        self._geofence: Any = None  # made on first use: plugins are only constructed when used
        self._snapshot: FcState | None = None

    async def start(self) -> None:
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        _forward_mavsdk_log()
        cfg = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        self._sdk = Mavsdk(cfg)
        try:
            await self._sdk.add_any_connection(self.mavsdk_url)
        except Exception as exc:
            await self.close()
            raise FcUnavailable(f"cannot open {self.mavsdk_url}: {exc}") from None
        system = await self._sdk.first_autopilot(timeout_s=self._timeout_s)
        if system is None:
            await self.close()
            raise FcUnavailable(f"no autopilot heartbeat on {self.mavsdk_url} within {self._timeout_s:g} s")
        self._system = system
        for _ in range(int(self._timeout_s / CONNECTED_POLL_S)):
            if await system.is_connected():
                break
            await asyncio.sleep(CONNECTED_POLL_S)
        else:
            await self.close()
            raise FcUnavailable(f"autopilot on {self.mavsdk_url} never reported a heartbeat")
        self._cache["connected"] = True
        self.telemetry = TelemetryAsync(system)
        self.action = ActionAsync(system)
        self.offboard = OffboardAsync(system)
        t = self.telemetry
        self._watch("position", t.subscribe_position)
        self._watch("home", t.subscribe_home)
        self._watch("armed", t.subscribe_armed)
        self._watch("flight_mode", t.subscribe_flight_mode)
        self._watch("landed_state", t.subscribe_landed_state)
        self._watch("attitude", t.subscribe_attitude_euler)
        self._watch("velocity", t.subscribe_velocity_ned)
        self._watch("battery", t.subscribe_battery)
        self._watch("gps", t.subscribe_gps_info)
        self._watch("health", t.subscribe_health)
        self._watch("local", t.subscribe_position_velocity_ned)
        self._tasks.append(asyncio.get_running_loop().create_task(self._poll_connection(), name="mavsdk connection"))
        try:  # `subscribe_home` yields only on new messages: seed it from the cache
            self._cache["home"] = await t.home()
        except Exception:
            pass

    def _watch(self, name: str, subscribe: Callable[[], AsyncIterator[Any]]) -> None:
        async def pump() -> None:
            async for value in subscribe():
                self._cache[name] = value
                self._snapshot = None

        self._tasks.append(asyncio.get_running_loop().create_task(pump(), name=f"mavsdk {name}"))

    async def _poll_connection(self) -> None:
        while True:
            connected = await self._system.is_connected()
            if connected != self._cache["connected"]:
                log.warning("flight controller %s", "connected" if connected else "lost")
                self._cache["connected"] = connected
                self._snapshot = None
            await asyncio.sleep(CONNECTED_POLL_S)

    def state(self) -> FcState:
        if self._snapshot is None:
            self._snapshot = self._build_state()
        return self._snapshot

    def _build_state(self) -> FcState:
        c = self._cache
        pos, home, att = c.get("position"), c.get("home"), c.get("attitude")
        vel, bat, gps, health, local = c.get("velocity"), c.get("battery"), c.get("gps"), c.get("health"), c.get("local")
        home_s = None
        if home is not None and not math.isnan(home.latitude_deg):
            home_s = Home(lat=home.latitude_deg, lon=home.longitude_deg, alt=home.absolute_altitude_m)
        position = None
        if pos is not None and not math.isnan(pos.latitude_deg):
            position = Position(lat=pos.latitude_deg, lon=pos.longitude_deg, alt=pos.absolute_altitude_m, rel_alt=pos.relative_altitude_m)
        return FcState(
            connected=c["connected"],
            armed=bool(c.get("armed", False)),
            flight_mode=c["flight_mode"].name.lower() if "flight_mode" in c else "unknown",
            landed_state=c["landed_state"].name.lower() if "landed_state" in c else "unknown",
            position=position,
            home=home_s,
            heading=normalize_deg(att.yaw_deg) if att is not None else 0.0,
            velocity=VelocityNed(north=vel.north_m_s, east=vel.east_m_s, down=vel.down_m_s) if vel else VelocityNed(),
            battery=(
                Battery(remaining_percent=_finite(bat.remaining_percent) / 100, voltage=_finite(bat.voltage_v))
                if bat is not None else None
            ),
            gps_info=GpsInfo(satellites=gps.num_satellites, fix_type=gps.fix_type.name.lower()) if gps else None,
            # Unknown health is not good health: until MAVSDK has a health report (about
            # 2 s after discovery; its first ones read all False) every check counts as
            # failing, so the drone is not `ready` before the autopilot would arm.
            health_failures=tuple(n for attr, n in _HEALTH.items() if health is None or not getattr(health, attr)),
            local_ned=(
                (local.position.north_m, local.position.east_m, local.position.down_m) if local is not None else None
            ),
        )

    # ----- commands -------------------------------------------------------------------

    async def _call(self, what: str, coro: Any) -> None:
        try:
            await coro
        except Exception as exc:
            result = getattr(exc, "result", None)
            name = getattr(result, "name", None) or getattr(getattr(result, "result", None), "name", None)
            raise FcRejected(f"{what}: {(name or str(exc)).lower().replace('_', ' ')}") from None

    async def arm(self) -> None:
        await self._call("arm", self.action.arm())

    async def disarm(self) -> None:
        await self._call("disarm", self.action.disarm())

    async def takeoff(self, alt_m: float) -> None:
        await self._call("takeoff altitude", self.action.set_takeoff_altitude(alt_m))
        await self._call("takeoff", self.action.takeoff())

    async def land(self) -> None:
        await self._call("land", self.action.land())

    async def goto(self, lat: float, lon: float, alt_amsl: float, yaw_deg: float | None, speed_mps: float | None) -> None:
        yaw = float("nan") if yaw_deg is None else yaw_deg
        await self._call("goto", self.action.goto_location(lat, lon, alt_amsl, yaw))
        if speed_mps is not None:
            await self._call("speed", self.action.set_current_speed(speed_mps))

    async def return_to_launch(self, alt_m: float) -> None:
        await self._call("return altitude", self.action.set_return_to_launch_altitude(alt_m))
        await self._call("return", self.action.return_to_launch())

    async def hold(self) -> None:
        await self._call("hold", self.action.hold())

    async def start_offboard(self) -> None:
        await self._call("start offboard", self.offboard.start())

    async def stop_offboard(self) -> None:
        await self._call("stop offboard", self.offboard.stop())

    async def set_setpoint(self, kind: str, values: dict[str, float | None]) -> None:
        from mavsdk.plugins import offboard as o

        v = {k: (0.0 if val is None else float(val)) for k, val in values.items()}
        if kind == "position_ned":
            call = self.offboard.set_position_ned(o.PositionNedYaw(v["north"], v["east"], v["down"], v["yaw"]))
        elif kind == "velocity_ned":
            call = self.offboard.set_velocity_ned(o.VelocityNedYaw(v["north"], v["east"], v["down"], v["yaw"]))
        elif kind == "velocity_body":
            call = self.offboard.set_velocity_body(o.VelocityBodyYawspeed(v["forward"], v["right"], v["down"], v["yaw"]))
        elif kind == "attitude":
            call = self.offboard.set_attitude(o.Attitude(v["roll"], v["pitch"], v["yaw"], v["thrust"]))
        elif kind == "attitude_rate":
            call = self.offboard.set_attitude_rate(o.AttitudeRate(v["roll"], v["pitch"], v["yaw"], v["thrust"]))
        else:
            raise FcRejected(f"unknown setpoint {kind}")
        await self._call(kind, call)

    async def upload_fence(self, polygon: list[tuple[float, float]]) -> None:
        """The mission protocol with mission_type FENCE (MISSION_COUNT, an item per
        vertex, MISSION_ACK); returns on the autopilot's ACCEPTED. A refusal or no answer
        (MAVSDK retries for a few seconds) comes back as FcRejected with MAVSDK's result."""
        from mavsdk.asyncio.plugins.geofence import FenceType, GeofenceAsync, GeofenceData, Point, Polygon

        if self._system is None:
            raise FcUnavailable("fence: not connected to the flight controller")
        if self._geofence is None:
            self._geofence = GeofenceAsync(self._system)
        points = [Point(latitude_deg=lat, longitude_deg=lon) for lat, lon in polygon]
        data = GeofenceData(polygons=[Polygon(points=points, fence_type=FenceType.INCLUSION)], circles=[])
        await self._call("fence", self._geofence.upload_geofence(data))

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks)
        self._tasks.clear()
        self._geofence = None
        if self._sdk is not None:
            self._sdk.destroy()
            self._sdk = None


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
