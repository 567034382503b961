"""The ArduCopter personality of the simulated autopilot (issue 58): what ArduCopter 4.5
does differently from PX4 v1.16 towards a MAVSDK 4.x client, as measured on a real
ArduCopter SITL (shared/notes/ardupilot-facts.md), over the same vehicle model
(sim/vehicle.py). The MAVLink endpoint (sim/mavlink_endpoint.py) asks it first about
every command and for the heartbeat's mode; what it leaves alone is handled as PX4 does.

What differs, and how it is played here:
- the heartbeat says ARDUPILOTMEGA and carries ArduCopter's mode numbers (GUIDED 4,
  BRAKE 17, RTL 6, LAND 9, STABILIZE 0, …); the vehicle starts in STABILIZE;
- nothing but the heartbeat (armed and mode) streams until SET_MESSAGE_INTERVAL asks
  for it (`STREAMS`): not even SYS_STATUS, so a client that does not ask never hears the
  sensors healthy (seen on ArduCopter 4.5.7 SITL on serial0);
- takeoff, goto and offboard fly in GUIDED, and the mode stays GUIDED throughout (no
  TAKEOFF → HOLD step); NAV_TAKEOFF's param7 is the altitude above home; a takeoff
  disarmed is FAILED, leaving the GUIDED the client switched to;
- arming is refused (FAILED, "Arm: BRAKE mode not armable") in the modes ArduCopter
  cannot arm in, BRAKE among them, which is where MAVSDK's arm puts a vehicle it finds
  in RTL or LAND; a disarm in the air is FAILED;
- hold is BRAKE (MAVSDK's Hold), a speed change in BRAKE is FAILED, a reposition's yaw
  is ignored: a heading is CONDITION_YAW's, in GUIDED;
- after a landing (LAND or RTL) the vehicle disarms by itself and the mode stays what
  it was; landing is slower (1.5 m/s, 0.5 m/s in the last 10 m), takeoff too;
- mission item 0 is home: an uploaded item 0 is replaced by it;
- EKF_STATUS_REPORT (when asked for) has the absolute-position flag only with a 3D fix
  and healthy position checks: GUIDED arms only then;
- parameters have ArduPilot's names and a cast (not bytewise) encoding of integers.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mav

from dronefleet.schemas.telemetry import MANUAL_MODES
from dronefleet.sim.px4_params import Param
from dronefleet.sim.vehicle import Vehicle, VehicleParams

STABILIZE, ACRO, ALT_HOLD, AUTO, GUIDED, LOITER, RTL, CIRCLE, LAND, POSHOLD, BRAKE, SMART_RTL = (
    0, 1, 2, 3, 4, 5, 6, 7, 9, 16, 17, 21)
MODE_NAMES = {STABILIZE: "STABILIZE", ACRO: "ACRO", ALT_HOLD: "ALT_HOLD", AUTO: "AUTO", GUIDED: "GUIDED",
              LOITER: "LOITER", RTL: "RTL", CIRCLE: "CIRCLE", LAND: "LAND", POSHOLD: "POSHOLD", BRAKE: "BRAKE",
              SMART_RTL: "SMART_RTL"}
ARMABLE = frozenset({STABILIZE, ACRO, ALT_HOLD, GUIDED, LOITER, POSHOLD})
PILOT_MODES = frozenset({STABILIZE, ACRO, ALT_HOLD, POSHOLD})  # a pilot flies (MAVSDK: stabilized, acro, altctl, posctl)
FLIGHT_SW_VERSION = (4 << 24) | (5 << 16) | (7 << 8) | 255  # 4.5.7 official
REPOSITION_CHANGE_MODE = 1  # MAV_DO_REPOSITION_FLAGS_CHANGE_MODE

# Streams and their period (s) before anyone asks: the rest are 0 until SET_MESSAGE_INTERVAL.
STREAMS: dict[int, float] = {
    mav.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
}

EKF_STATUS_REPORT = apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT
# attitude, velocities, relative and absolute horizontal position, absolute vertical, predicted
_EKF_GOOD = 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512
_EKF_ABSOLUTE = 16 | 512

ACCEPTED, FAILED, UNSUPPORTED = mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_FAILED, mav.MAV_RESULT_UNSUPPORTED

# (result, a STATUSTEXT to send with it or None)
Answer = tuple[int, str | None]
Reposition = Callable[[list[float], "int | None"], int]  # the endpoint flies a DO_REPOSITION, returns its MAV_RESULT


def ekf_status_report(v: Vehicle) -> mav.MAVLink_message:
    absolute = v.fix_type not in ("no_gps", "no_fix", "fix_2d") and not (
        {"global_position", "local_position"} & set(v.health_failures))
    flags = _EKF_GOOD if absolute else _EKF_GOOD & ~_EKF_ABSOLUTE
    return apm.MAVLink_ekf_status_report_message(flags, 0.1, 0.1, 0.1, 0.1, 0.0, 0.0)


def tuned(params: VehicleParams) -> VehicleParams:
    """ArduCopter's timings on the vehicle model: a slower takeoff (10 m in about 9 s),
    LAND at 1.5 m/s then 0.5 m/s below 10 m (10 m in about 22 s), disarmed 1 s after
    touchdown (LAND_SPEED, LAND_ALT_LOW, DISARM_DELAY)."""
    return replace(params, takeoff_speed_mps=1.1, descent_speed_mps=1.5, land_speed_mps=0.5,
                   land_slow_below_m=10.0, disarm_after_land_s=1.0, rtl_min_alt_m=15.0)


def default_params(v: Vehicle) -> dict[str, Param]:
    """ArduCopter's names and types for what the vehicle model holds."""
    p = v.params
    return {
        "RTL_ALT": Param(round(p.rtl_min_alt_m * 100), mav.MAV_PARAM_TYPE_INT32),  # cm
        "WPNAV_SPEED": Param(p.cruise_speed_mps * 100),  # cm/s
        "WPNAV_SPEED_DN": Param(p.descent_speed_mps * 100),  # cm/s
        "LAND_SPEED": Param(round(p.land_speed_mps * 100), mav.MAV_PARAM_TYPE_INT16),  # cm/s
        "DISARM_DELAY": Param(round(p.disarm_after_land_s), mav.MAV_PARAM_TYPE_INT8),
        "FS_GCS_ENABLE": Param(0, mav.MAV_PARAM_TYPE_INT8),
        "FENCE_ENABLE": Param(0, mav.MAV_PARAM_TYPE_INT8),
    }


class ArduCopter:
    """ArduCopter's mode and its answers to commands, over one vehicle model."""

    autopilot = mav.MAV_AUTOPILOT_ARDUPILOTMEGA

    def __init__(self, vehicle: Vehicle) -> None:
        self.vehicle = vehicle
        self.mode = STABILIZE
        self._seen = vehicle.mode  # the model's own mode at the last look

    def custom_mode(self) -> int:
        self.follow()
        return self.mode

    def follow(self) -> None:
        """Follow what the model did on its own: a failsafe return or landing, a pilot's
        radio taking over (POSHOLD) or letting go (LOITER). Its other changes (a takeoff
        ending, setpoints stopping, a disarm after landing) keep ArduCopter's mode."""
        now = self.vehicle.mode
        if now == self._seen:
            return
        if now == "return_to_launch":
            self.mode = RTL
        elif now == "land":
            self.mode = LAND
        elif now in MANUAL_MODES and self.mode not in PILOT_MODES:
            self.mode = POSHOLD
        elif self._seen in MANUAL_MODES and now == "hold":
            self.mode = LOITER
        self._seen = now

    def command(self, command: int, p: list[float], frame: int | None,
                reposition: Reposition, rtl_alt_m: float) -> Answer | None:
        """ArduCopter's answer to a command, or None where it answers as PX4 does.
        `reposition(p, frame)` flies a DO_REPOSITION on the model (the endpoint's)."""
        self.follow()
        answer = self._command(command, p, frame, reposition, rtl_alt_m)
        self._seen = self.vehicle.mode  # what the command made of the model is ArduCopter's doing
        return answer

    def _command(self, command: int, p: list[float], frame: int | None,
                 reposition: Reposition, rtl_alt_m: float) -> Answer | None:
        v = self.vehicle
        if command == mav.MAV_CMD_DO_SET_MODE:
            return self.set_mode(int(p[1]), rtl_alt_m)
        if command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] < 0.5:
                why = v.disarm()
                return (ACCEPTED, None) if why is None else (FAILED, "Disarm: vehicle in the air")
            if v.armed:
                return ACCEPTED, None
            if self.mode not in ARMABLE:
                return FAILED, f"Arm: {MODE_NAMES.get(self.mode, self.mode)} mode not armable"
            why = v.arm()
            return (ACCEPTED, None) if why is None else (FAILED, f"PreArm: {why}")
        if command == mav.MAV_CMD_NAV_TAKEOFF:
            if self.mode != GUIDED:
                return FAILED, None
            if not v.armed:
                return FAILED, None
            why = v.takeoff(p[6] if math.isfinite(p[6]) and p[6] > 0 else v.params.takeoff_alt_m)
            return (ACCEPTED, None) if why is None else (FAILED, None)
        if command == mav.MAV_CMD_DO_REPOSITION:
            if self.mode != GUIDED and not int(p[1]) & REPOSITION_CHANGE_MODE:
                return FAILED, None
            if not v.armed or not v.in_air:
                return FAILED, None
            result = reposition([p[0], p[1], p[2], math.nan, *p[4:]], frame)  # 4.5 ignores the yaw
            if result != ACCEPTED:
                return FAILED, None
            self.mode = GUIDED
            return ACCEPTED, None
        if command == mav.MAV_CMD_CONDITION_YAW:  # p1 the heading (deg), p4 1: relative to the current one
            if self.mode != GUIDED:
                return FAILED, None
            heading = p[0] + (v.heading if p[3] >= 0.5 else 0.0)
            return (ACCEPTED, None) if v.face(heading) is None else (FAILED, None)
        if command == mav.MAV_CMD_DO_CHANGE_SPEED:
            if self.mode == BRAKE:
                return FAILED, None
            return None
        if command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self.set_mode(RTL, rtl_alt_m)
        if command == mav.MAV_CMD_NAV_LAND:
            return self.set_mode(LAND, rtl_alt_m)
        return None

    def set_mode(self, mode: int, rtl_alt_m: float) -> Answer:
        v = self.vehicle
        if mode not in MODE_NAMES or mode in (AUTO, CIRCLE, SMART_RTL):
            return UNSUPPORTED, None  # no missions or circles flown here
        if v.mode in MANUAL_MODES and mode not in PILOT_MODES:
            v.inject_manual(False)
        if mode == GUIDED:
            if v.armed and v.in_air and v.start_offboard() is not None:  # setpoints streaming: they fly it
                v.hold()
        elif mode in (BRAKE, LOITER):
            v.hold()
        elif mode == RTL:
            v.return_to_launch(rtl_alt_m)
        elif mode == LAND:
            v.land()
        elif mode in PILOT_MODES and v.in_air:
            v.inject_manual(True)
        self.mode = mode
        return ACCEPTED, None
