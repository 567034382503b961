"""The MAVSDK flight-controller adapter: PX4 and ArduCopter through mavsdk 4.x, the
native binding (libmavsdk in-process, no mavsdk_server).

Telemetry streams (`subscribe_*`) feed a cache that `state()` reads; commands go
through the Action and Offboard plugins and come back as FcRejected with MAVSDK's
result on refusal. Facts this relies on (shared/notes/mavsdk-facts.md): wait for
`is_connected()` (a HEARTBEAT) before commanding, or MAVSDK takes non-PX4 paths;
takeoff/RTL altitudes are parameter writes; `set_current_speed` replaces the
removed `set_maximum_speed`; serial URLs need a baud rate; `udp://host:port` means
outbound; heartbeat-driven fields lag a command by up to a second.

The heartbeat says which autopilot it is; where ArduCopter differs
(shared/notes/ardupilot-facts.md) the adapter follows `AUTOPILOTS[make]`, one small
table, with the same calls otherwise:
- ArduPilot streams no position, battery, GPS, home, sensor health (SYS_STATUS) or
  estimator flags until asked: the rates are asked for; its global position counts as
  good once the estimator has an absolute position (EKF_STATUS_REPORT), as GUIDED needs;
- takeoff, goto and offboard fly in GUIDED, which MAVSDK reports as `offboard`: the
  state says `takeoff` while a takeoff climbs, `offboard` only while our setpoints fly
  it, `hold` otherwise (a PX4 drone says the same at those moments);
- a pilot's mode (STABILIZE, ALT_HOLD, …) on a disarmed drone is the autopilot's idle,
  reported `ready`, not a pilot taking over (armed, it is one);
- arming from RTL, LAND or BRAKE fails (MAVSDK's arm switches them to BRAKE, which is
  not armable): the adapter switches to GUIDED first;
- the return altitude is the integer parameter RTL_ALT in centimetres;
- a goto's yaw is ignored (ArduCopter 4.5): the heading follows as CONDITION_YAW;
- an uploaded fence acts only with FENCE_ENABLE = 1: the upload sets it.

PX4 flies a reposition (a goto) in HOLD itself: a switch to HOLD then changes nothing and
the drone flies on to the goto's target (seen on PX4 1.16 SITL), so a hold in the air is
also a reposition to where the drone is.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

from dronefleet.agent.fc_port import Changes, FcRejected, FcState, FcUnavailable, Listener
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.geo import normalize_deg
from dronefleet.schemas.telemetry import Battery, GpsInfo, Home, Position, VelocityNed

log = logging.getLogger(__name__)

DEFAULT_BAUD = 57600
CONNECTED_POLL_S = 0.25
MODE_SEEN_S = 3.0  # a mode change shows in the heartbeat within a second: wait this long at most
_HEALTH = {
    "is_gyrometer_calibration_ok": "gyrometer",
    "is_accelerometer_calibration_ok": "accelerometer",
    "is_magnetometer_calibration_ok": "magnetometer",
    "is_local_position_ok": "local_position",
    "is_global_position_ok": "global_position",
    "is_home_position_ok": "home_position",
}
SYS_STATUS = 1  # the MAVLink message the sensors' health comes in
EKF_STATUS_REPORT = 193  # ArduPilot's estimator flags
EKF_POS_HORIZ_ABS = 16  # its flag for an absolute horizontal position
SET_MESSAGE_INTERVAL = 511  # MAV_CMD_SET_MESSAGE_INTERVAL


@dataclass(frozen=True)
class Autopilot:
    """What the adapter does differently for one make of autopilot."""

    name: str
    rates_hz: dict[str, float] = field(default_factory=dict)  # telemetry.set_rate_<name>(hz) at the start
    # MAVLink message id → Hz, asked for at the start where MAVSDK has no rate call for it
    message_rates_hz: dict[int, float] = field(default_factory=dict)
    guided: bool = False  # takeoff, goto and offboard share one mode (GUIDED), reported `offboard` by MAVSDK
    idle_modes: frozenset[str] = frozenset()  # modes a disarmed drone idles in (not a pilot's)
    arm_from_mode: int | None = None  # custom mode to switch to before arming, unless in it already
    return_alt_param: tuple[str, float] | None = None  # integer parameter and its unit in metres (None: MAVSDK's)
    yaw_command: bool = False  # a goto's yaw is ignored: the heading is sent as CONDITION_YAW after it
    fence_enable_param: str | None = None  # an uploaded fence acts only once this integer parameter is 1
    # A reposition flies in the hold mode itself, so switching to hold changes nothing and
    # the drone flies on: a hold in the air is also a reposition to where the drone is.
    hold_repositions: bool = False
    # Its health report says the global position is good ≈ 20 s before its EKF has an
    # absolute position (ArduCopter refuses to arm in GUIDED until then: "Need Position
    # Estimate"): the position counts as good only once EKF_STATUS_REPORT says so.
    position_from_ekf: bool = False


GUIDED_MODE = 4  # ArduCopter's GUIDED custom mode
# The streams the agent reads many times a second, at the rate its telemetry is sent: PX4
# streams ATTITUDE at 100 Hz and GLOBAL_POSITION_INT at 50 Hz on its onboard link, each
# one a Python callback through MAVSDK (px4-facts.md; 5.9 % of a core at rest, not 2 %).
FLIGHT_RATES_HZ = {"position": 10.0, "position_velocity_ned": 10.0, "velocity_ned": 10.0, "attitude_euler": 10.0}
# … while it is armed. Disarmed, nothing it does needs them more than twice a second (a
# drone on the ground moves only when carried), and each message is a callback from
# libmavsdk's thread into the loop: at rest, the four streams at 10 Hz were most of the
# agent's 2.3-2.9 % of a core. Arming is read from the heartbeat, not from these.
REST_RATE_HZ = 2.0
AUTOPILOTS = {
    "px4": Autopilot("px4", rates_hz=FLIGHT_RATES_HZ, hold_repositions=True),
    "ardupilot": Autopilot(
        "ardupilot",
        rates_hz={**FLIGHT_RATES_HZ, "gps_info": 2.0, "battery": 1.0, "home": 1.0, "landed_state": 2.0},
        message_rates_hz={SYS_STATUS: 1.0, EKF_STATUS_REPORT: 1.0},
        guided=True, idle_modes=frozenset({"stabilized", "altctl", "posctl", "acro", "manual"}),
        arm_from_mode=GUIDED_MODE, return_alt_param=("RTL_ALT", 0.01), yaw_command=True,
        fence_enable_param="FENCE_ENABLE", position_from_ekf=True,
    ),
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
        self._direct: Any = None  # MavlinkDirect, likewise
        self._param: Any = None  # Param, likewise
        self._snapshot: FcState | None = None
        self._mode_seen = asyncio.Event()  # a flight mode arrived
        self.autopilot = AUTOPILOTS["px4"]
        self._offboard = False  # our offboard stream flies it (GUIDED autopilots: not told by the mode)
        self._takeoff_to: float | None = None  # a takeoff's altitude above home while it climbs
        self._changes = Changes()
        self._flight_rates: bool | None = None  # the flight streams asked for at flight rates (armed) or at rest
        self._rates_task: asyncio.Task[None] | None = None  # asking for them again, after arming changed

    @property
    def make(self) -> str | None:
        return self.autopilot.name

    def watch(self, listener: Listener) -> None:
        self._changes.watch(listener)

    def _changed(self) -> None:
        """The cache changed in a way that may move connection, arming, mode or landed
        state: tell the listeners now, not at their next poll."""
        self._snapshot = None
        self._changes.offer(self.state())

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
        from mavsdk.autopilot import Autopilot as Make

        self.autopilot = AUTOPILOTS["ardupilot" if await system.autopilot_type() == Make.ARDUPILOT else "px4"]
        log.info("flight controller %s: %s", self.url, self.autopilot.name)
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
        await self._set_rates({name: hz for name, hz in self.autopilot.rates_hz.items() if name not in FLIGHT_RATES_HZ})
        self._rates_task = asyncio.get_running_loop().create_task(self._follow_arming(), name="mavsdk rates")
        await asyncio.shield(self._rates_task)
        for message, hz in self.autopilot.message_rates_hz.items():
            try:
                await self._command_long(f"message {message} rate", SET_MESSAGE_INTERVAL, message, 1e6 / hz)
            except FcRejected as exc:
                log.warning("flight controller: %s", exc)
        if self.autopilot.position_from_ekf:
            self._tasks.append(asyncio.get_running_loop().create_task(self._watch_ekf(), name="mavsdk ekf"))
        try:  # `subscribe_home` yields only on new messages: seed it from the cache
            self._cache["home"] = await t.home()
        except Exception:
            pass

    async def _set_rates(self, rates_hz: dict[str, float]) -> None:
        for name, hz in rates_hz.items():
            try:
                await getattr(self.telemetry, f"set_rate_{name}")(hz)
            except Exception as exc:  # noqa: BLE001 - the stream may come anyway; say so and go on
                log.warning("flight controller: telemetry rate %s %g Hz not set: %s", name, hz, exc)

    async def _follow_arming(self) -> None:
        """The flight streams at the autopilot's flight rates while it is armed,
        REST_RATE_HZ otherwise, asked for again until they match its last arming (one
        asker at a time, so the last edge's rates are the ones that stay)."""
        flight = {name: hz for name, hz in self.autopilot.rates_hz.items() if name in FLIGHT_RATES_HZ}
        while (armed := bool(self._cache.get("armed", False))) != self._flight_rates:
            self._flight_rates = armed
            await self._set_rates(flight if armed else {name: min(hz, REST_RATE_HZ) for name, hz in flight.items()})
        self._rates_task = None

    def _watch(self, name: str, subscribe: Callable[[], AsyncIterator[Any]]) -> None:
        edges = name in ("armed", "flight_mode", "landed_state")

        async def pump() -> None:
            async for value in subscribe():
                self._cache[name] = value
                self._snapshot = None
                if name == "armed" and self._flight_rates not in (None, bool(value)) and self._rates_task is None:
                    self._rates_task = asyncio.get_running_loop().create_task(self._follow_arming(), name="mavsdk rates")
                if name == "flight_mode":
                    self._mode_seen.set()
                # A GUIDED takeoff's reported mode turns on its altitude (`_mode`).
                if edges or (name == "position" and self._takeoff_to is not None):
                    self._changes.offer(self.state())

        self._tasks.append(asyncio.get_running_loop().create_task(pump(), name=f"mavsdk {name}"))

    async def _watch_ekf(self) -> None:
        import json

        async for message in self._mavlink_direct().subscribe_message("EKF_STATUS_REPORT"):
            position = bool(json.loads(message.fields_json or "{}").get("flags", 0) & EKF_POS_HORIZ_ABS)
            if position != self._cache.get("ekf_position"):
                self._cache["ekf_position"] = position
                self._snapshot = None

    async def _poll_connection(self) -> None:
        while True:
            connected = await self._system.is_connected()
            if connected != self._cache["connected"]:
                log.warning("flight controller %s", "connected" if connected else "lost")
                self._cache["connected"] = connected
                self._changed()
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
        armed = bool(c.get("armed", False))
        return FcState(
            connected=c["connected"],
            armed=armed,
            flight_mode=self._mode(c["flight_mode"].name.lower() if "flight_mode" in c else "unknown", armed, position),
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
            health_failures=self._health_failures(health),
            local_ned=(
                (local.position.north_m, local.position.east_m, local.position.down_m) if local is not None else None
            ),
        )

    def _health_failures(self, health: Any) -> tuple[str, ...]:
        failing = [n for attr, n in _HEALTH.items() if health is None or not getattr(health, attr)]
        if self.autopilot.position_from_ekf and not self._cache.get("ekf_position") and "global_position" not in failing:
            failing.append("global_position")
        return tuple(failing)

    def _mode(self, reported: str, armed: bool, position: Position | None) -> str:
        """Fleet's name for what the autopilot is doing (see the module's docstring)."""
        ap = self.autopilot
        if reported != "offboard":
            self._offboard = False  # out of GUIDED (a failsafe, a pilot): our setpoints no longer fly it
        if not armed:
            self._takeoff_to = None
            return "ready" if reported in ap.idle_modes else reported
        if not ap.guided or reported != "offboard":
            return reported
        if self._offboard:
            return "offboard"
        if self._takeoff_to is not None and position is not None and position.rel_alt < self._takeoff_to * 0.95:
            return "takeoff"
        self._takeoff_to = None
        return "hold"

    # ----- commands -------------------------------------------------------------------

    async def _call(self, what: str, coro: Any) -> None:
        try:
            await coro
        except Exception as exc:
            result = getattr(exc, "result", None)
            name = getattr(result, "name", None) or getattr(getattr(result, "result", None), "name", None)
            raise FcRejected(f"{what}: {(name or str(exc)).lower().replace('_', ' ')}") from None

    async def arm(self) -> None:
        mode = self.autopilot.arm_from_mode
        if mode is not None and self._reported_mode() != "OFFBOARD":
            await self._set_mode(mode)  # MAVSDK's arm would switch RTL or LAND to BRAKE, which cannot arm
            # armed in the idle mode reads as a pilot's: arm once the mode the autopilot reports is ours
            try:
                async with asyncio.timeout(MODE_SEEN_S):
                    while True:
                        self._mode_seen.clear()
                        if self._reported_mode() == "OFFBOARD":
                            break
                        await self._mode_seen.wait()
            except TimeoutError:
                log.warning("flight controller: GUIDED not reported %g s after it was accepted; arming", MODE_SEEN_S)
        await self._call("arm", self.action.arm())

    def _reported_mode(self) -> str | None:
        mode = self._cache.get("flight_mode")
        return None if mode is None else str(mode.name)

    async def _set_mode(self, custom_mode: int) -> None:
        """DO_SET_MODE with an autopilot's own mode number (MAVSDK's modes are PX4's names)."""
        armed = 128 if self._cache.get("armed") else 0  # MAV_MODE_FLAG_SAFETY_ARMED
        await self._command_long(f"mode {custom_mode}", 176, 1 | armed, custom_mode)  # MAV_CMD_DO_SET_MODE

    async def _command_long(self, what: str, command: int, *params: float) -> None:
        """A COMMAND_LONG MAVSDK has no call for, answered by the autopilot's COMMAND_ACK."""
        import json

        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        sysid = await self._system.get_system_id()
        values = [*params, *[0.0] * (7 - len(params))]
        fields = {"target_system": sysid, "target_component": 1, "command": command, "confirmation": 0,
                  **{f"param{i}": float(v) for i, v in enumerate(values, 1)}}
        try:
            ack = await self._mavlink_direct().send_command(MavlinkMessage("COMMAND_LONG", 0, 0, sysid, 1, json.dumps(fields)))
        except Exception as exc:
            raise FcRejected(f"{what}: {exc}") from None
        result = json.loads(ack.fields_json or "{}").get("result")
        if result != 0:  # MAV_RESULT_ACCEPTED
            raise FcRejected(f"{what}: refused (MAV_RESULT {result})")

    async def disarm(self) -> None:
        await self._call("disarm", self.action.disarm())

    async def takeoff(self, alt_m: float) -> None:
        await self._call("takeoff altitude", self.action.set_takeoff_altitude(alt_m))
        await self._call("takeoff", self.action.takeoff())
        self._takeoff_to = alt_m
        self._changed()

    async def land(self) -> None:
        await self._call("land", self.action.land())

    async def goto(self, lat: float, lon: float, alt_amsl: float, yaw_deg: float | None, speed_mps: float | None) -> None:
        yaw = float("nan") if yaw_deg is None else yaw_deg
        await self._call("goto", self.action.goto_location(lat, lon, alt_amsl, yaw))
        self._takeoff_to = None
        self._changed()
        if yaw_deg is not None and self.autopilot.yaw_command:
            await self._command_long("yaw", 115, yaw_deg, 0.0, 0.0, 0.0)  # MAV_CMD_CONDITION_YAW, absolute
        if speed_mps is not None:
            await self._call("speed", self.action.set_current_speed(speed_mps))

    async def return_to_launch(self, alt_m: float) -> None:
        param = self.autopilot.return_alt_param
        if param is None:
            await self._call("return altitude", self.action.set_return_to_launch_altitude(alt_m))
        else:  # a preference: the return flies at the autopilot's own altitude if it refuses ours
            name, unit_m = param
            try:
                await self._call("return altitude", self._params().set_param_int(name, round(alt_m / unit_m)))
            except FcRejected as exc:
                log.warning("flight controller: %s (%s) not set, returning at the autopilot's own: %s", name, alt_m, exc)
        await self._call("return", self.action.return_to_launch())
        self._takeoff_to = None
        self._changed()

    async def hold(self) -> None:
        await self._call("hold", self.action.hold())
        here = self.state().position
        if self.autopilot.hold_repositions and here is not None and self._cache.get("armed"):
            await self._call("hold", self.action.goto_location(here.lat, here.lon, here.alt, float("nan")))
        self._takeoff_to = None
        self._changed()

    async def start_offboard(self) -> None:
        await self._call("start offboard", self.offboard.start())
        self._offboard, self._takeoff_to = True, None
        self._changed()

    async def stop_offboard(self) -> None:
        self._offboard = False
        self._changed()
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
        if self.autopilot.fence_enable_param is not None:
            await self._call("fence enable", self._params().set_param_int(self.autopilot.fence_enable_param, 1 if polygon else 0))

    def _mavlink_direct(self) -> Any:
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync

        if self._direct is None:
            self._direct = MavlinkDirectAsync(self._system)
        return self._direct

    def _params(self) -> Any:
        from mavsdk.asyncio.plugins.param import ParamAsync

        if self._param is None:
            self._param = ParamAsync(self._system)
        return self._param

    async def close(self) -> None:
        tasks = [*self._tasks, *([self._rates_task] if self._rates_task is not None else [])]
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)
        self._tasks.clear()
        self._rates_task = None
        self._geofence = self._direct = self._param = None
        if self._sdk is not None:
            self._sdk.destroy()
            self._sdk = None


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
