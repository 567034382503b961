"""A PX4-like MAVLink vehicle: the sim/ vehicle model behind a UDP MAVLink link.

Built with pymavlink (no hand-rolled encoding). Towards MAVSDK 4.x it behaves like
PX4 v1.16 SITL (shared/notes/px4-facts.md, mavsdk-facts.md): it sends to
127.0.0.1:14540+i as PX4 SITL does and answers whoever talks to it; the surface it
implements is listed in sim/MAVLINK.md. Every COMMAND_LONG/COMMAND_INT is
acknowledged (UNSUPPORTED for what it does not implement), REQUEST_MESSAGE is
answered with the message or UNSUPPORTED, parameter writes are echoed; plans
(mission, geofence, rally points) go through PX4's mission protocol (MissionManager),
and an accepted inclusion polygon becomes `vehicle.fence`.
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

from schemas.telemetry import MANUAL_MODES
from sim.vehicle import Vehicle

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
FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 255  # 1.16.0 official


@dataclass
class _Param:
    value: float
    kind: int = mav.MAV_PARAM_TYPE_REAL32


def default_params(v: Vehicle) -> dict[str, _Param]:
    p = v.params
    return {
        "MIS_TAKEOFF_ALT": _Param(p.takeoff_alt_m),
        "RTL_RETURN_ALT": _Param(p.rtl_min_alt_m),
        "MPC_XY_CRUISE": _Param(p.cruise_speed_mps),
        "MPC_XY_VEL_MAX": _Param(p.max_speed_mps),
        "MPC_TKO_SPEED": _Param(p.takeoff_speed_mps),
        "MPC_LAND_SPEED": _Param(p.land_speed_mps),
        "COM_DISARM_LAND": _Param(p.disarm_after_land_s),
        "COM_DISARM_PRFLT": _Param(p.disarm_preflight_s),
        "COM_OF_LOSS_T": _Param(p.offboard_loss_s),
        "NAV_DLL_ACT": _Param(0, mav.MAV_PARAM_TYPE_INT32),
    }


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
    ) -> None:
        self.vehicle = vehicle
        self.sysid = sysid
        self.outputs = list(outputs)
        self.peers: set[tuple[str, int]] = set()
        self.params = default_params(vehicle)
        self.periods = dict(DEFAULT_STREAMS)
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
        self.missions = MissionManager(self)

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
            self.missions.tick(now)
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
        summary = (v.mode, v.armed, v.landed_state, v.connected)
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
            handler = getattr(self, f"_on_{name.lower()}", None) or getattr(self.missions, f"on_{name.lower()}", None)
            if handler is not None:
                try:
                    handler(msg)
                except Exception:
                    log.exception("sysid %d: handling %s failed", self.sysid, name)

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
            self.periods[msg_id] = (
                DEFAULT_STREAMS.get(msg_id, 0.0) if interval_us == 0 else -1.0 if interval_us < 0 else interval_us / 1e6
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
        name = _param_name(msg.param_id)
        param = self.params.get(name)
        if param is None:
            return  # unknown params are ignored, as on PX4 (the client times out)
        value = msg.param_value
        if param.kind == mav.MAV_PARAM_TYPE_INT32:  # PX4 bytewise encoding
            value = float(struct.unpack("<i", struct.pack("<f", value))[0])
        param.value = value
        self._apply_param(name, value)
        self._send_param(name)

    def _apply_param(self, name: str, value: float) -> None:
        p = self.vehicle.params
        if name == "MPC_XY_CRUISE":
            self.vehicle.cruise_speed = value
        elif name == "MIS_TAKEOFF_ALT":
            p.takeoff_alt_m = value
        elif name == "RTL_RETURN_ALT":
            p.rtl_min_alt_m = value

    def _on_param_request_read(self, msg: mav.MAVLink_param_request_read_message) -> None:
        names = list(self.params)
        name = _param_name(msg.param_id) if msg.param_index < 0 else (
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
        if param.kind == mav.MAV_PARAM_TYPE_INT32:
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
        main, sub = PX4_MODES.get(v.mode, (4, 3))
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if v.armed else 0)
        status = mav.MAV_STATE_ACTIVE if v.armed else mav.MAV_STATE_STANDBY
        return self._mav.heartbeat_encode(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, (main << 16) | (sub << 24), status
        )

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
            caps, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1000 + self.sysid,
        )


# ----- the mission protocol, as PX4 v1.16's MavlinkMissionManager ----------------------
# (src/modules/mavlink/mavlink_mission.cpp): plans (mission, geofence, rally points) are
# uploaded with MISSION_COUNT, the vehicle requesting each item in turn and re-requesting
# the awaited one every 0.25 s, ending with its MISSION_ACK; downloaded with
# MISSION_REQUEST_LIST, the client requesting each item and ending with its ACK; cleared
# with MISSION_CLEAR_ALL. One transfer at a time; 5 s without a word from the partner
# abandons it ("Operation timeout").

MISSION, FENCE, RALLY = mav.MAV_MISSION_TYPE_MISSION, mav.MAV_MISSION_TYPE_FENCE, mav.MAV_MISSION_TYPE_RALLY
# PX4's limits: DM_KEY_FENCE_POINTS_MAX, DM_KEY_SAFE_POINTS_MAX; the mission's is per board.
MISSION_MAX_COUNT = {MISSION: 500, FENCE: 64, RALLY: 32}
MISSION_RETRY_S = 0.25  # MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT
MISSION_TIMEOUT_S = 5.0  # MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT
IDLE, SENDLIST, GETLIST = "idle", "sendlist", "getlist"

_MISSION_ACCEPTED, _MISSION_ERROR = mav.MAV_MISSION_ACCEPTED, mav.MAV_MISSION_ERROR
_FRAME_MISSION = mav.MAV_FRAME_MISSION
_FRAMES_FLOAT = {mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT}
_FRAMES_INT = {mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_FRAMES_RELATIVE = {mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_VERTEX = {mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION}
_CIRCLE = {mav.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, mav.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION}
_ROI = {mav.MAV_CMD_NAV_ROI, mav.MAV_CMD_DO_SET_ROI}
# Positional commands PX4 takes in a global frame, with the params (1-4) it keeps and
# sends back; a 4 here is a yaw (deg), which comes back in [0, 360).
_GLOBAL_COMMANDS: dict[int, tuple[int, ...]] = {
    mav.MAV_CMD_NAV_WAYPOINT: (1, 2, 4), mav.MAV_CMD_NAV_LOITER_UNLIM: (3, 4), mav.MAV_CMD_NAV_LOITER_TIME: (1, 2, 3),
    mav.MAV_CMD_NAV_LAND: (2, 4), mav.MAV_CMD_NAV_TAKEOFF: (4,), mav.MAV_CMD_NAV_LOITER_TO_ALT: (1, 2),
    mav.MAV_CMD_NAV_ROI: (), mav.MAV_CMD_DO_SET_ROI: (), mav.MAV_CMD_DO_SET_ROI_LOCATION: (),
    mav.MAV_CMD_NAV_VTOL_TAKEOFF: (4,), mav.MAV_CMD_NAV_VTOL_LAND: (4,), mav.MAV_CMD_CONDITION_GATE: (),
    mav.MAV_CMD_NAV_FENCE_RETURN_POINT: (), **dict.fromkeys(_VERTEX | _CIRCLE, (1,)),
    mav.MAV_CMD_NAV_RALLY_POINT: (), mav.MAV_CMD_COMPONENT_ARM_DISARM: (), mav.MAV_CMD_DO_AUTOTUNE_ENABLE: (),
}
_YAW_KEPT = {mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_LOITER_UNLIM, mav.MAV_CMD_NAV_LAND, mav.MAV_CMD_NAV_TAKEOFF,
             mav.MAV_CMD_NAV_VTOL_TAKEOFF, mav.MAV_CMD_NAV_VTOL_LAND}
# Commands without a position (MAV_FRAME_MISSION); all seven params are kept.
_MISSION_FRAME_COMMANDS = {
    getattr(mav, f"MAV_CMD_{name}") for name in (
        "DO_JUMP NAV_ROI DO_SET_ROI DO_WINCH DO_GRIPPER DO_CHANGE_SPEED DO_SET_HOME DO_LAND_START DO_TRIGGER_CONTROL "
        "DO_DIGICAM_CONTROL DO_MOUNT_CONFIGURE DO_MOUNT_CONTROL DO_GIMBAL_MANAGER_PITCHYAW SET_CAMERA_FOCUS "
        "DO_GIMBAL_MANAGER_CONFIGURE IMAGE_START_CAPTURE IMAGE_STOP_CAPTURE VIDEO_START_CAPTURE VIDEO_STOP_CAPTURE "
        "DO_CONTROL_VIDEO DO_SET_CAM_TRIGG_DIST OBLIQUE_SURVEY DO_SET_CAM_TRIGG_INTERVAL SET_CAMERA_MODE "
        "SET_CAMERA_SOURCE DO_VTOL_TRANSITION NAV_DELAY NAV_RETURN_TO_LAUNCH DO_SET_ROI_WPNEXT_OFFSET DO_SET_ROI_NONE "
        "CONDITION_DELAY CONDITION_DISTANCE DO_SET_ACTUATOR DO_AUTOTUNE_ENABLE COMPONENT_ARM_DISARM"
    ).split()
}
_NOT_IN_A_MISSION = _VERTEX | _CIRCLE | {mav.MAV_CMD_NAV_RALLY_POINT}


@dataclass(frozen=True)
class MissionItem:
    """One stored plan item as PX4 keeps it: in a global frame x/y are lat/lon in
    degrees and z the altitude; in MAV_FRAME_MISSION x/y/z are params 5-7."""

    command: int
    frame: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    z: float
    autocontinue: int = 0


def parse_mission_item(msg: mav.MAVLink_message, int_mode: bool) -> MissionItem | int:
    """The item a MISSION_ITEM(_INT) carries, or the MAV_MISSION_RESULT refusing it
    (PX4's parse_mavlink_mission_item)."""
    frame, command = msg.frame, msg.command
    p = (msg.param1, msg.param2, msg.param3, msg.param4)
    if frame in _FRAMES_FLOAT or (int_mode and frame in _FRAMES_INT):
        keep = _GLOBAL_COMMANDS.get(command)
        if keep is None:
            return mav.MAV_MISSION_UNSUPPORTED
        if command in _ROI and int(p[0]) not in (mav.MAV_ROI_LOCATION, mav.MAV_ROI_NONE):
            return mav.MAV_MISSION_INVALID_PARAM1
        kept = [p[i] if i + 1 in keep else 0.0 for i in range(4)]
        if command in _VERTEX:
            kept[0] = float(int(p[0] + 0.5))  # the vertex count
        if command in _YAW_KEPT:
            kept[3] = p[3] % 360.0
        lat, lon = (msg.x * 1e-7, msg.y * 1e-7) if int_mode else (msg.x, msg.y)
        return MissionItem(command, frame, (kept[0], kept[1], kept[2], kept[3]), lat, lon, msg.z, msg.autocontinue)
    if frame == _FRAME_MISSION:
        if command not in _MISSION_FRAME_COMMANDS:
            return mav.MAV_MISSION_UNSUPPORTED
        if command in _ROI and int(p[0]) not in (mav.MAV_ROI_NONE, mav.MAV_ROI_WPNEXT, mav.MAV_ROI_WPINDEX):
            return mav.MAV_MISSION_INVALID_PARAM1
        return MissionItem(command, frame, p, msg.x, msg.y, msg.z, msg.autocontinue)
    return mav.MAV_MISSION_UNSUPPORTED_FRAME


def fence_polygons(items: list[MissionItem]) -> list[tuple[int, list[tuple[float, float]]]]:
    """The (command, [(lat, lon), …]) polygons of a geofence plan: each vertex item's
    param1 is the vertex count of its polygon."""
    polygons, i = [], 0
    while i < len(items):
        item = items[i]
        count = int(item.params[0]) if item.command in _VERTEX else 0
        if count > 0:
            polygons.append((item.command, [(v.x, v.y) for v in items[i:i + count]]))
            i += count
        else:
            i += 1
    return polygons


class MissionManager:
    """The mission protocol of one simulated autopilot (see the section comment). Like
    PX4 it starts in float mode (MISSION_REQUEST / MISSION_ITEM) and switches to the
    int messages when the client uses them or refuses the float ones with
    MAV_MISSION_UNSUPPORTED, as MAVSDK does."""

    def __init__(self, endpoint: MavlinkVehicle) -> None:
        self._ep = endpoint
        self.plans: dict[int, list[MissionItem]] = {MISSION: [], FENCE: [], RALLY: []}
        self.current_seq = 0  # the mission's current item (items sent with current=1)
        self.state = IDLE
        self.mission_type = MISSION  # of the transfer under way, or the last one
        self.int_mode = False
        self.partner = (0, 0)
        self.transfer_count = 0
        self.transfer_seq = 0
        self._transfer_items: list[MissionItem] = []
        self._transfer_current = -1
        self._in_progress = False  # PX4's _transfer_in_progress: an upload holds the store
        self._last_sent = 0.0
        self._last_recv = 0.0

    # ----- helpers -------------------------------------------------------------------

    def _count(self, mission_type: int) -> int:
        return len(self.plans.get(mission_type, ()))

    def _for_me(self, msg: mav.MAVLink_message) -> bool:
        return msg.target_system == self._ep.sysid and msg.target_component in (
            mav.MAV_COMP_ID_AUTOPILOT1, mav.MAV_COMP_ID_MISSIONPLANNER, mav.MAV_COMP_ID_ALL,
        )

    def _send(self, msg: mav.MAVLink_message) -> None:
        self._ep._send(msg)

    def _critical(self, text: str) -> None:
        self._send(self._ep._mav.statustext_encode(mav.MAV_SEVERITY_CRITICAL, text.encode()))

    def _ack(self, to: tuple[int, int], result: int) -> None:
        self._send(self._ep._mav.mission_ack_encode(to[0], to[1], result, self.mission_type))

    def _request(self, seq: int) -> None:
        if seq >= MISSION_MAX_COUNT.get(self.mission_type, 0):
            self._critical("ERROR: Waypoint index exceeds list capacity")
            return
        self._last_sent = time.monotonic()
        encode = self._ep._mav.mission_request_int_encode if self.int_mode else self._ep._mav.mission_request_encode
        self._send(encode(self.partner[0], self.partner[1], seq, self.mission_type))

    def _send_item(self, seq: int) -> None:
        item = self.plans[self.mission_type][seq]
        frame, params, x, y = item.frame, item.params, item.x, item.y
        if frame != _FRAME_MISSION:  # PX4 keeps a fence vertex's altitude as absolute
            relative = frame in _FRAMES_RELATIVE and self.mission_type != FENCE
            if self.int_mode:
                frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT if relative else mav.MAV_FRAME_GLOBAL_INT
                x, y = round(x * 1e7), round(y * 1e7)
            else:
                frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT if relative else mav.MAV_FRAME_GLOBAL
        elif self.int_mode:
            x, y = round(x), round(y)
        autocontinue = 0 if self.mission_type == FENCE else item.autocontinue
        encode = self._ep._mav.mission_item_int_encode if self.int_mode else self._ep._mav.mission_item_encode
        self._last_sent = time.monotonic()
        self._send(encode(
            self.partner[0], self.partner[1], seq, frame, item.command, int(seq == self.current_seq), autocontinue,
            *params, x, y, item.z, self.mission_type,
        ))

    def _store(self, mission_type: int, items: list[MissionItem], current: int = 0) -> None:
        if mission_type not in self.plans:
            return
        self.plans[mission_type] = items
        if mission_type == MISSION:
            self.current_seq = current
        elif mission_type == FENCE:
            self._apply_fence()

    def _apply_fence(self) -> None:
        vehicle, items = self._ep.vehicle, self.plans[FENCE]
        inclusions = [vertices for command, vertices in fence_polygons(items)
                      if command == mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION]
        vehicle.fence = inclusions[0] if inclusions else []
        if not items:
            log.info("sysid %d: fence cleared", self._ep.sysid)
            return
        vertices = sum(1 for item in items if item.command in _VERTEX)
        circles = sum(1 for item in items if item.command in _CIRCLE)
        log.info("sysid %d: fence uploaded: %d vertices%s", self._ep.sysid, vertices,
                 f", {circles} circles" if circles else "")

    def tick(self, now: float) -> None:
        """Re-request the awaited item, or give the transfer up (PX4's send())."""
        if self.state == GETLIST and self._last_sent > 0 and now - self._last_sent > MISSION_RETRY_S:
            self._request(self.transfer_seq)
        elif self.state != IDLE and self._last_recv > 0 and now - self._last_recv > MISSION_TIMEOUT_S:
            self._critical("Operation timeout")
            log.info("sysid %d: mission transfer (type %d) timed out", self._ep.sysid, self.mission_type)
            self.state = IDLE
            self._in_progress = False
        elif self.state == IDLE:
            self._last_sent = self._last_recv = 0.0

    # ----- messages ------------------------------------------------------------------

    def on_mission_count(self, msg: mav.MAVLink_mission_count_message) -> None:
        if not self._for_me(msg):
            return
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.state == IDLE:
            self._last_recv = time.monotonic()
            if self._in_progress:
                self._ack(sender, _MISSION_ERROR)
                return
            self._in_progress = True
            self.partner, self.mission_type = sender, msg.mission_type
            if msg.count > MISSION_MAX_COUNT.get(self.mission_type, 0):
                self._ack(self.partner, mav.MAV_MISSION_NO_SPACE)
                self._in_progress = False
                return
            if msg.count == 0:  # an empty plan clears the store
                self._store(self.mission_type, [])
                self._ack(self.partner, _MISSION_ACCEPTED)
                self._in_progress = False
                return
            if self.mission_type not in self.plans:
                self._in_progress = False
                self._ack(self.partner, mav.MAV_MISSION_INVALID)
                return
            self.state, self.transfer_seq, self.transfer_count = GETLIST, 0, msg.count
            self._transfer_items, self._transfer_current = [], -1
        elif self.state == GETLIST:
            self._last_recv = time.monotonic()
            if sender != self.partner:
                self._ack(sender, _MISSION_ERROR)
                return
            if self.transfer_seq != 0:  # at seq 0 our first request was lost: ask again
                self._critical("WPM: REJ. CMD: Busy")
                self._ack(self.partner, _MISSION_ERROR)
                return
        else:
            self._critical("WPM: IGN MISSION_COUNT: Busy")
            self._ack(sender, _MISSION_ERROR)
            return
        self._request(self.transfer_seq)

    def on_mission_item(self, msg: mav.MAVLink_mission_item_message) -> None:
        self.int_mode = False
        self._on_item(msg)

    def on_mission_item_int(self, msg: mav.MAVLink_mission_item_int_message) -> None:
        self.int_mode = True
        self._on_item(msg)

    def _on_item(self, msg: mav.MAVLink_message) -> None:
        if not self._for_me(msg):
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.partner:
            self._critical("REJ. MIS ITEM: partner id mismatch")
            return
        if msg.mission_type != self.mission_type:
            self._ack(self.partner, _MISSION_ERROR)
            return
        if self.state == IDLE:  # a repeat of the last item: our ACK was lost
            if self.transfer_seq == msg.seq + 1:
                self._ack(self.partner, _MISSION_ACCEPTED)
            else:
                self._critical("IGN MISSION_ITEM: No transfer")
                self._ack(self.partner, _MISSION_ERROR)
            return
        if self.state != GETLIST:
            self._critical("IGN MISSION_ITEM: Busy")
            self._ack(self.partner, _MISSION_ERROR)
            return
        self._last_recv = time.monotonic()
        if msg.seq != self.transfer_seq:
            return  # not the one asked for: the retry asks again
        item = parse_mission_item(msg, self.int_mode)
        if isinstance(item, int):
            self._critical("IGN MISSION_ITEM: Invalid item")
            self._abort(item)
            return
        if self.mission_type == MISSION and item.command in _NOT_IN_A_MISSION:
            self._abort(_MISSION_ERROR)
            return
        if self.mission_type == FENCE and item.command in _VERTEX and item.params[0] < 3:
            log.info("sysid %d: fence refused: a polygon of %d vertices", self._ep.sysid, int(item.params[0]))
            self._abort(_MISSION_ERROR)  # PX4: "Fence: too few vertices"
            return
        if msg.current:
            self._transfer_current = msg.seq
        self._transfer_items.append(item)
        self.transfer_seq = msg.seq + 1
        if self.transfer_seq < self.transfer_count:
            self._request(self.transfer_seq)
            return
        self._store(self.mission_type, self._transfer_items, self._transfer_current)
        self.state = IDLE
        self._ack(self.partner, _MISSION_ACCEPTED)
        self._in_progress = False

    def _abort(self, result: int) -> None:
        self._ack(self.partner, result)
        self.state = IDLE
        self._in_progress = False

    def on_mission_request_list(self, msg: mav.MAVLink_mission_request_list_message) -> None:
        if not self._for_me(msg):
            return
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.transfer_seq == self._count(self.mission_type):
            # PX4: all items went out but the ACK never came (a quick reconnect). Its
            # check also ends an upload at that seq, leaving the store held (as PX4 does).
            self.state = IDLE
        if self.state == IDLE or (
            self.state == SENDLIST and msg.mission_type == self.mission_type and sender == self.partner
        ):
            self._last_recv = self._last_sent = time.monotonic()
            self.state, self.mission_type, self.partner = SENDLIST, msg.mission_type, sender
            self.transfer_seq, self.transfer_count = 0, self._count(msg.mission_type)
            self._send(self._ep._mav.mission_count_encode(sender[0], sender[1], self.transfer_count, self.mission_type))
        else:
            self._send(self._ep._mav.statustext_encode(
                mav.MAV_SEVERITY_INFO, b"Mission download request ignored, already active",
            ))

    def on_mission_request(self, msg: mav.MAVLink_mission_request_message) -> None:
        self.int_mode = False
        self._on_request(msg)

    def on_mission_request_int(self, msg: mav.MAVLink_mission_request_int_message) -> None:
        self.int_mode = True
        self._on_request(msg)

    def _on_request(self, msg: mav.MAVLink_message) -> None:
        if not self._for_me(msg):
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.partner:
            self._critical("WPM: REJ. CMD: partner id mismatch")
            return
        if self.state == IDLE:
            return  # PX4 ignores these silently (some OSDs send them)
        if self.state != SENDLIST:
            self._critical("WPM: REJ. CMD: Busy")
            return
        if msg.mission_type != self.mission_type:
            return
        self._last_recv = time.monotonic()
        if msg.seq == self.transfer_seq and self.transfer_seq < self.transfer_count:
            self.transfer_seq += 1
        elif msg.seq != self.transfer_seq - 1:  # not the last one again either
            self.state = IDLE
            self._ack(self.partner, _MISSION_ERROR)
            self._critical("WPM: REJ. CMD: Req. WP was unexpected")
            return
        if msg.seq < self._count(self.mission_type):
            self._send_item(msg.seq)
        else:
            self.state = IDLE
            self._ack(self.partner, _MISSION_ERROR)
            self._critical("WPM: REJ. CMD: Req. WP was unexpected")

    def on_mission_ack(self, msg: mav.MAVLink_mission_ack_message) -> None:
        if not self._for_me(msg):
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.partner:
            self._critical("REJ. WP CMD: partner id mismatch")
            return
        if self.state == SENDLIST and msg.mission_type == self.mission_type:
            self._last_recv = time.monotonic()
            self.state = IDLE  # the download is over, whatever the result
        elif self.state == GETLIST:
            if msg.type == mav.MAV_MISSION_UNSUPPORTED:  # the client wants the other encoding
                self.int_mode = not self.int_mode
                self._request(self.transfer_seq)
            elif msg.type == mav.MAV_MISSION_OPERATION_CANCELLED:
                self.state = IDLE
                self._in_progress = False

    def on_mission_clear_all(self, msg: mav.MAVLink_mission_clear_all_message) -> None:
        if not self._for_me(msg):
            return
        if self.state != IDLE:
            self._critical("WPM: IGN CLEAR CMD: Busy")
            return
        self._last_recv = time.monotonic()
        self.mission_type = msg.mission_type
        for mission_type in (MISSION, FENCE, RALLY) if msg.mission_type == mav.MAV_MISSION_TYPE_ALL else (msg.mission_type,):
            self._store(mission_type, [])
        self._ack((msg.get_srcSystem(), msg.get_srcComponent()), _MISSION_ACCEPTED)


_BUILDERS: dict[int, Callable[[MavlinkVehicle], mav.MAVLink_message]] = {
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
}


def _param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode(errors="replace")
    return raw.rstrip("\x00")


def _euler(q: list[float]) -> tuple[float, float, float]:
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)
