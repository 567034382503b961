"""A PX4-like (or ArduCopter-like) MAVLink vehicle: the sim/ vehicle model behind a UDP
MAVLink link.

Built with pymavlink (no hand-rolled encoding). Towards MAVSDK 4.x it behaves like
PX4 v1.16 SITL (shared/notes/px4-facts.md, mavsdk-facts.md): it sends to
127.0.0.1:14540+i as PX4 SITL does and answers whoever talks to it; the surface it
implements is listed in sim/MAVLINK.md. Every COMMAND_LONG/COMMAND_INT is
acknowledged (UNSUPPORTED for what it does not implement), REQUEST_MESSAGE is
answered with the message or UNSUPPORTED, parameter writes are echoed; plans
(mission, geofence, rally points) go through PX4's mission protocol (MissionManager),
and an accepted inclusion polygon becomes `vehicle.fence`. With `autopilot="ardupilot"`
it is an ArduCopter 4.5 instead where ArduCopter differs (sim/ardupilot.py: its modes,
streams, refusals and timings).
"""

from __future__ import annotations

import asyncio
import logging
import math
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mav

from dronefleet.schemas.telemetry import MANUAL_MODES
from dronefleet.sim import ardupilot
from dronefleet.sim.autopilot_params import BY_AUTOPILOT, tune
from dronefleet.sim.mission_protocol import MissionItem, MissionProtocol
from dronefleet.sim.px4_params import default_params, param_name
from dronefleet.sim.vehicle import Vehicle

log = logging.getLogger(__name__)

# PX4 custom modes: custom_mode = main << 16 | sub << 24 (mavsdk-facts.md §5).
PX4_MODES: dict[str, tuple[int, int]] = {
    "manual": (1, 0), "altctl": (2, 0), "posctl": (3, 0), "ready": (4, 1), "takeoff": (4, 2),
    "hold": (4, 3), "mission": (4, 4), "return_to_launch": (4, 5), "land": (4, 6),
    "follow_me": (4, 8), "acro": (5, 0), "offboard": (6, 0), "stabilized": (7, 0), "rattitude": (8, 0),
}
_MODE_OF = {v: k for k, v in PX4_MODES.items()}
_LANDED = {"unknown": 0, "on_ground": 1, "in_air": 2, "taking_off": 3, "landing": 4}
_FIX = {"no_gps": 0, "no_fix": 1, "fix_2d": 2, "fix_3d": 3, "fix_dgps": 4, "rtk_float": 5, "rtk_fixed": 6}
_SENSOR_BITS = {"gyrometer": 1, "accelerometer": 2, "magnetometer": 4, "global_position": 32, "local_position": 32}
_PREARM = 0x10000000
_PRESENT = 1 | 2 | 4 | 8 | 32 | _PREARM

ACCEPTED, TEMP_REJECTED, DENIED, UNSUPPORTED, FAILED = (
    mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_TEMPORARILY_REJECTED, mav.MAV_RESULT_DENIED,
    mav.MAV_RESULT_UNSUPPORTED, mav.MAV_RESULT_FAILED,
)
AUTOPILOTS = ("px4", "ardupilot")
FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 255  # 1.16.0 official


# Streams and their default period (s); SET_MESSAGE_INTERVAL changes them.
DEFAULT_STREAMS: dict[int, float] = {
    mav.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.1,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0.1,
    mav.MAVLINK_MSG_ID_ATTITUDE: 0.1,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: 0.5,
    mav.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mav.MAVLINK_MSG_ID_HOME_POSITION: 5.0,
}


@dataclass
class EndpointStats:
    received: dict[str, int] = field(default_factory=dict)


def param_names(autopilot: str) -> set[str]:
    """The parameters a simulated `autopilot` keeps (a client may read and set them)."""
    vehicle = Vehicle(0.0, 0.0, 0.0)
    if autopilot == "ardupilot":
        vehicle.params = ardupilot.tuned(vehicle.params)
        return set(ardupilot.default_params(vehicle))
    return set(default_params(vehicle))


class MavlinkVehicle(asyncio.DatagramProtocol):
    """One simulated autopilot on one UDP socket."""

    def __init__(
        self,
        vehicle: Vehicle,
        sysid: int,
        outputs: list[tuple[str, int]],
        *,
        step_s: float = 0.02,
        on_change: Callable[[MavlinkVehicle], None] | None = None,
        autopilot: str = "px4",
    ) -> None:
        if autopilot not in AUTOPILOTS:
            raise ValueError(f"unknown autopilot {autopilot!r} (known: {', '.join(AUTOPILOTS)})")
        self.vehicle = vehicle
        self.sysid = sysid
        self.outputs = list(outputs)
        self.peers: set[tuple[str, int]] = set()
        self.copter = ardupilot.ArduCopter(vehicle) if autopilot == "ardupilot" else None
        if self.copter is not None:
            vehicle.params = ardupilot.tuned(vehicle.params)
        self.params = default_params(vehicle) if self.copter is None else ardupilot.default_params(vehicle)
        self.periods = dict(DEFAULT_STREAMS if self.copter is None else ardupilot.STREAMS)
        self.stats = EndpointStats()
        self._mav = mav.MAVLink(None, srcSystem=sysid, srcComponent=mav.MAV_COMP_ID_AUTOPILOT1)
        self._mav.robust_parsing = True
        self._transport: asyncio.DatagramTransport | None = None
        self._step_s = step_s
        self._next_due: dict[int, float] = {}
        self._boot = time.monotonic()
        self._home_sent = False
        self._on_change = on_change
        self._last_summary: tuple[object, ...] = ()
        self._fence: list[tuple[float, float]] = []  # the uploaded inclusion polygon ([] none)
        self.missions = MissionProtocol(sysid, self._mav, on_fence=self._set_fence,
                                        home=None if self.copter is None else self._home_item)

    # ----- lifecycle -----------------------------------------------------------------

    async def start(self, bind: tuple[str, int], sock: socket.socket | None = None) -> None:
        """Listen on `bind`; or on `sock` bound there (a socket made in a drone's
        network namespace, so the MAVLink link stays on the drone)."""
        loop = asyncio.get_running_loop()
        if sock is None:
            await loop.create_datagram_endpoint(lambda: self, local_addr=bind)
        else:
            sock.bind(bind)
            await loop.create_datagram_endpoint(lambda: self, sock=sock)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport  # type: ignore[assignment]

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    @property
    def mode_name(self) -> str:
        """The mode as its autopilot names it (PX4's as the vehicle model keeps them)."""
        if self.copter is None:
            return self.vehicle.mode
        mode = self.copter.custom_mode()
        return f"{ardupilot.MODE_NAMES.get(mode, str(mode))} (ardupilot)"

    @property
    def local_port(self) -> int:
        assert self._transport is not None
        return self._transport.get_extra_info("sockname")[1]

    async def run(self) -> None:
        """Step the vehicle and send due streams until cancelled."""
        last = time.monotonic()
        while True:
            await asyncio.sleep(self._step_s)
            now = time.monotonic()
            self.vehicle.step(now - last)
            last = now
            for out in self.missions.tick(now):
                self._send(out)
            if not self.vehicle.connected:
                self.vehicle.events.clear()
                continue
            for text in self.vehicle.events:
                self._send(self._mav.statustext_encode(mav.MAV_SEVERITY_INFO, text[:50].encode()))
            self.vehicle.events.clear()
            for msg_id, period in self.periods.items():
                if period > 0 and now >= self._next_due.get(msg_id, 0.0):
                    self._next_due[msg_id] = now + period
                    self._send_stream(msg_id)
            self._report_change()

    def _report_change(self) -> None:
        v = self.vehicle
        summary = (self.mode_name, v.armed, v.landed_state, v.connected)
        if summary != self._last_summary:
            self._last_summary = summary
            if self._on_change is not None:
                self._on_change(self)

    # ----- I/O -----------------------------------------------------------------------

    def _send(self, msg: mav.MAVLink_message) -> None:
        if self._transport is None or not self.vehicle.connected:
            return
        data = msg.pack(self._mav)
        for addr in self.outputs + [p for p in self.peers if p not in self.outputs]:
            self._transport.sendto(data, addr)

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if not self.vehicle.connected:
            return  # a pulled link hears nothing
        self.peers.add(addr)
        try:
            messages = self._mav.parse_buffer(data) or []
        except mav.MAVError:
            return
        for msg in messages:
            name = msg.get_type()
            self.stats.received[name] = self.stats.received.get(name, 0) + 1
            handler = getattr(self, f"_on_{name.lower()}", None)
            try:
                if handler is not None:
                    handler(msg)
                elif self.missions.handles(name):
                    for out in self.missions.handle(msg, time.monotonic()):
                        self._send(out)
            except Exception:
                log.exception("sysid %d: handling %s failed", self.sysid, name)

    def _set_fence(self, polygon: list[tuple[float, float]]) -> None:
        self._fence = polygon
        if self.copter is None or self.params["FENCE_ENABLE"].value:  # ArduCopter: held once enabled
            self.vehicle.fence = polygon

    # ----- incoming messages ---------------------------------------------------------

    def _on_command_long(self, msg: mav.MAVLink_command_long_message) -> None:
        if msg.target_system not in (0, self.sysid):
            return
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
        self._ack(msg, self._command(msg.command, params, frame=None))

    def _on_command_int(self, msg: mav.MAVLink_command_int_message) -> None:
        if msg.target_system not in (0, self.sysid):
            return
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z]
        self._ack(msg, self._command(msg.command, params, frame=msg.frame))

    def _ack(self, msg: mav.MAVLink_message, result: int) -> None:
        self._send(self._mav.command_ack_encode(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        ))

    def _command(self, command: int, p: list[float], frame: int | None) -> int:
        v = self.vehicle
        if self.copter is not None:
            rtl_alt_m = self.params["RTL_ALT"].value / 100
            answer = self.copter.command(command, p, frame, self._reposition, rtl_alt_m)
            if answer is not None:
                result, text = answer
                if text is not None:
                    self._send(self._mav.statustext_encode(mav.MAV_SEVERITY_CRITICAL, text[:50].encode()))
                return result
        if command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._result(v.arm() if p[0] >= 0.5 else v.disarm())
        if command == mav.MAV_CMD_NAV_TAKEOFF:
            alt = self.params["MIS_TAKEOFF_ALT"].value
            if not math.isnan(p[6]):  # non-PX4 clients send an AMSL altitude
                alt = p[6] - v.home.alt
            return self._result(v.takeoff(alt))
        if command == mav.MAV_CMD_NAV_LAND:
            return self._result(v.land())
        if command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._result(v.return_to_launch(self.params["RTL_RETURN_ALT"].value))
        if command == mav.MAV_CMD_DO_SET_MODE:
            return self._set_mode(int(p[1]), int(p[2]))
        if command == mav.MAV_CMD_DO_CHANGE_SPEED:
            return self._result(v.set_speed(p[1])) if p[1] > 0 else ACCEPTED
        if command == mav.MAV_CMD_DO_REPOSITION:
            return self._reposition(p, frame)
        if command in (mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mav.MAV_CMD_GET_HOME_POSITION):
            msg_id = {
                mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                mav.MAV_CMD_GET_HOME_POSITION: mav.MAVLINK_MSG_ID_HOME_POSITION,
            }.get(command, int(p[0]))
            message = self._build(msg_id)
            if message is None:
                return UNSUPPORTED
            asyncio.get_running_loop().call_soon(self._send, message)  # after the ACK, as PX4 does
            return ACCEPTED
        if command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int(p[0]), p[1]
            if self._build(msg_id) is None:
                return UNSUPPORTED
            defaults = DEFAULT_STREAMS if self.copter is None else ardupilot.STREAMS
            self.periods[msg_id] = (
                defaults.get(msg_id, 0.0) if interval_us == 0 else -1.0 if interval_us < 0 else interval_us / 1e6
            )
            return ACCEPTED
        return UNSUPPORTED

    def _result(self, reason: str | None) -> int:
        if reason is None:
            return ACCEPTED
        self._send(self._mav.statustext_encode(mav.MAV_SEVERITY_CRITICAL, reason[:50].encode()))
        return DENIED

    def _set_mode(self, main: int, sub: int) -> int:
        v = self.vehicle
        mode = _MODE_OF.get((main, sub)) or _MODE_OF.get((main, 0))
        if mode is None or mode in ("mission", "follow_me", "ready"):
            return UNSUPPORTED
        if mode == "hold":
            if v.mode in MANUAL_MODES:
                v.inject_manual(False)
            if v.mode == "hold":
                return ACCEPTED  # PX4 flies a reposition in HOLD: switching to it changes nothing
            return self._result(v.hold())
        if mode == "return_to_launch":
            return self._result(v.return_to_launch(self.params["RTL_RETURN_ALT"].value))
        if mode == "land":
            return self._result(v.land())
        if mode == "takeoff":
            return self._result(v.takeoff(self.params["MIS_TAKEOFF_ALT"].value))
        if mode == "offboard":
            # PX4 refuses the switch until setpoints stream (TEMPORARILY_REJECTED).
            return TEMP_REJECTED if v.start_offboard() is not None else ACCEPTED
        v.inject_manual(True)
        v.mode = mode
        return ACCEPTED

    def _reposition(self, p: list[float], frame: int | None) -> int:
        v = self.vehicle
        lat, lon = (p[4] / 1e7, p[5] / 1e7) if frame is not None else (p[4], p[5])
        alt = p[6]
        if frame in (mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            alt += v.home.alt
        speed = None if math.isnan(p[0]) or p[0] <= 0 else p[0]
        yaw = None if math.isnan(p[3]) else math.degrees(p[3])
        return self._result(v.goto(lat, lon, alt, yaw, speed))

    def _on_set_position_target_local_ned(self, msg: mav.MAVLink_set_position_target_local_ned_message) -> None:
        mask = msg.type_mask
        use_pos = not mask & 0b111
        use_yaw = not mask & (1 << 10)
        use_yaw_rate = not mask & (1 << 11)
        yaw = math.degrees(msg.yaw) if use_yaw else None
        if use_pos:
            self.vehicle.set_setpoint("position_ned", north=msg.x, east=msg.y, down=msg.z, yaw=yaw)
        elif msg.coordinate_frame == mav.MAV_FRAME_BODY_NED:
            rate = math.degrees(msg.yaw_rate) if use_yaw_rate else 0.0
            self.vehicle.set_setpoint("velocity_body", forward=msg.vx, right=msg.vy, down=msg.vz, yaw=rate)
        else:
            self.vehicle.set_setpoint("velocity_ned", north=msg.vx, east=msg.vy, down=msg.vz, yaw=yaw)

    def _on_set_attitude_target(self, msg: mav.MAVLink_set_attitude_target_message) -> None:
        if msg.type_mask & (1 << 7):  # attitude ignored: body rates
            self.vehicle.set_setpoint(
                "attitude_rate", roll=math.degrees(msg.body_roll_rate), pitch=math.degrees(msg.body_pitch_rate),
                yaw=math.degrees(msg.body_yaw_rate), thrust=msg.thrust,
            )
        else:
            roll, pitch, yaw = _euler(msg.q)
            self.vehicle.set_setpoint("attitude", roll=roll, pitch=pitch, yaw=yaw, thrust=msg.thrust)

    def _on_param_set(self, msg: mav.MAVLink_param_set_message) -> None:
        name = param_name(msg.param_id)
        param = self.params.get(name)
        if param is None:
            return  # unknown params are ignored, as on PX4 (the client times out)
        value = msg.param_value
        if param.kind == mav.MAV_PARAM_TYPE_INT32 and self.copter is None:  # PX4 bytewise encoding
            value = float(struct.unpack("<i", struct.pack("<f", value))[0])
        try:
            self.set_param(name, value)
        except ValueError as exc:  # kept as it was; the client reads the value back
            log.warning("vehicle %d: PARAM_SET %s refused: %s", self.sysid, name, exc)
        self._send_param(name)

    def set_param(self, name: str, value: float) -> None:
        """Set a parameter as a ground station's PARAM_SET does (`fleet sim --param`);
        an integer parameter takes the value rounded (ArduPilot casts it). KeyError for a
        name this autopilot does not have, ValueError for a value the vehicle cannot fly
        with (the parameter keeps its value)."""
        param = self.params[name]
        value = float(round(value)) if param.kind != mav.MAV_PARAM_TYPE_REAL32 else value
        self._apply_param(name, value)
        param.value = value

    def _apply_param(self, name: str, value: float) -> None:
        model = BY_AUTOPILOT["px4" if self.copter is None else "ardupilot"]
        if name in model:
            tune(self.vehicle, model, name, value)
        elif name == "FENCE_ENABLE":
            self.vehicle.fence = self._fence if value else []

    def _on_param_request_read(self, msg: mav.MAVLink_param_request_read_message) -> None:
        names = list(self.params)
        name = param_name(msg.param_id) if msg.param_index < 0 else (
            names[msg.param_index] if msg.param_index < len(names) else ""
        )
        if name in self.params:
            self._send_param(name)

    def _on_param_request_list(self, msg: mav.MAVLink_message) -> None:
        for name in self.params:
            self._send_param(name)

    def _send_param(self, name: str) -> None:
        param = self.params[name]
        value = param.value
        if param.kind == mav.MAV_PARAM_TYPE_INT32 and self.copter is None:
            value = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        names = list(self.params)
        self._send(self._mav.param_value_encode(name.encode(), value, param.kind, len(names), names.index(name)))

    def _on_timesync(self, msg: mav.MAVLink_timesync_message) -> None:
        if msg.tc1 == 0:
            self._send(self._mav.timesync_encode(time.monotonic_ns(), msg.ts1))

    def _on_ping(self, msg: mav.MAVLink_ping_message) -> None:
        if msg.target_system == 0:
            self._send(self._mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    # ----- outgoing messages ---------------------------------------------------------

    def _send_stream(self, msg_id: int) -> None:
        message = self._build(msg_id)
        if message is not None:
            self._send(message)

    def _build(self, msg_id: int) -> mav.MAVLink_message | None:
        builder = _BUILDERS.get(msg_id)
        return builder(self) if builder is not None else None

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF

    def heartbeat(self) -> mav.MAVLink_message:
        v = self.vehicle
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if v.armed else 0)
        status = mav.MAV_STATE_ACTIVE if v.armed else mav.MAV_STATE_STANDBY
        if self.copter is not None:
            return self._mav.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR, ardupilot.ArduCopter.autopilot, base, self.copter.custom_mode(), status)
        main, sub = PX4_MODES.get(v.mode, (4, 3))
        return self._mav.heartbeat_encode(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, (main << 16) | (sub << 24), status
        )

    def _home_item(self) -> MissionItem:
        """ArduPilot's mission item 0: home."""
        home = self.vehicle.home
        return MissionItem(mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_FRAME_GLOBAL, (0.0, 0.0, 0.0, 0.0), home.lat, home.lon,
                           home.alt, 1)

    def global_position_int(self) -> mav.MAVLink_message:
        v = self.vehicle
        pos = v.position()
        return self._mav.global_position_int_encode(
            self._boot_ms(), round(pos.lat * 1e7), round(pos.lon * 1e7), round(pos.alt * 1000),
            round(pos.rel_alt * 1000), round(v.vn * 100), round(v.ve * 100), round(v.vd * 100),
            round(v.heading * 100) % 36000,
        )

    def local_position_ned(self) -> mav.MAVLink_message:
        v = self.vehicle
        n, e, d = v.local_ned()
        return self._mav.local_position_ned_encode(self._boot_ms(), n, e, d, v.vn, v.ve, v.vd)

    def attitude(self) -> mav.MAVLink_message:
        yaw = math.radians(self.vehicle.heading)
        if yaw > math.pi:
            yaw -= 2 * math.pi
        return self._mav.attitude_encode(self._boot_ms(), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)

    def gps_raw_int(self) -> mav.MAVLink_message:
        v = self.vehicle
        pos, gps = v.position(), v.gps()
        vel = round(math.hypot(v.vn, v.ve) * 100)
        return self._mav.gps_raw_int_encode(
            int(time.time() * 1e6), _FIX[gps.fix_type], round(pos.lat * 1e7), round(pos.lon * 1e7),
            round(pos.alt * 1000), 80, 120, vel, round(v.heading * 100) % 36000, gps.satellites,
        )

    def sys_status(self) -> mav.MAVLink_message:
        v = self.vehicle
        health = _PRESENT
        for failure in v.health_failures:
            health &= ~_SENSOR_BITS.get(failure, 0)
        if v.fix_type in ("no_gps", "no_fix"):
            health &= ~32
        if v.health_failures or v.fix_type in ("no_gps", "no_fix", "fix_2d"):
            health &= ~_PREARM
        battery = v.battery_state()
        return self._mav.sys_status_encode(
            _PRESENT, _PRESENT, health, 100, round(battery.voltage * 1000), -1,
            round(battery.remaining_percent * 100), 0, 0, 0, 0, 0, 0,
        )

    def ekf_status_report(self) -> mav.MAVLink_message | None:
        """ArduPilot's estimator flags (an ardupilotmega message: PX4 has none)."""
        if self.copter is None:
            return None
        return ardupilot.ekf_status_report(self.vehicle)

    def battery_status(self) -> mav.MAVLink_message:
        battery = self.vehicle.battery_state()
        cells = self.vehicle.params.battery_cells
        cell_mv = round(battery.voltage * 1000 / cells)
        voltages = [cell_mv] * cells + [65535] * (10 - cells)
        return self._mav.battery_status_encode(
            0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO, 2500, voltages, -1, -1, -1,
            round(battery.remaining_percent * 100),
        )

    def extended_sys_state(self) -> mav.MAVLink_message:
        return self._mav.extended_sys_state_encode(mav.MAV_VTOL_STATE_MC, _LANDED[self.vehicle.landed_state])

    def home_position(self) -> mav.MAVLink_message:
        home = self.vehicle.home
        return self._mav.home_position_encode(
            round(home.lat * 1e7), round(home.lon * 1e7), round(home.alt * 1000), 0.0, 0.0, 0.0,
            [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(time.time() * 1e6),
        )

    def autopilot_version(self) -> mav.MAVLink_message:
        caps = (
            mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | mav.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        )
        return self._mav.autopilot_version_encode(
            caps, FLIGHT_SW_VERSION if self.copter is None else ardupilot.FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1000 + self.sysid,
        )


_BUILDERS: dict[int, Callable[[MavlinkVehicle], mav.MAVLink_message | None]] = {
    mav.MAVLINK_MSG_ID_HEARTBEAT: MavlinkVehicle.heartbeat,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: MavlinkVehicle.global_position_int,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: MavlinkVehicle.local_position_ned,
    mav.MAVLINK_MSG_ID_ATTITUDE: MavlinkVehicle.attitude,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: MavlinkVehicle.gps_raw_int,
    mav.MAVLINK_MSG_ID_SYS_STATUS: MavlinkVehicle.sys_status,
    mav.MAVLINK_MSG_ID_BATTERY_STATUS: MavlinkVehicle.battery_status,
    mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: MavlinkVehicle.extended_sys_state,
    mav.MAVLINK_MSG_ID_HOME_POSITION: MavlinkVehicle.home_position,
    mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION: MavlinkVehicle.autopilot_version,
    ardupilot.EKF_STATUS_REPORT: MavlinkVehicle.ekf_status_report,
}


def _euler(q: list[float]) -> tuple[float, float, float]:
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)
