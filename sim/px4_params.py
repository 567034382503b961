"""The parameters the simulated autopilot keeps (PX4 v1.16 names and types), taken
from the vehicle model's settings, and the name in a PARAM_* message."""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mav

from dronefleet.sim.vehicle import Vehicle


@dataclass
class Param:
    value: float
    kind: int = mav.MAV_PARAM_TYPE_REAL32


def default_params(v: Vehicle) -> dict[str, Param]:
    p = v.params
    return {
        "MIS_TAKEOFF_ALT": Param(p.takeoff_alt_m),
        "RTL_RETURN_ALT": Param(p.rtl_min_alt_m),
        "MPC_XY_CRUISE": Param(p.cruise_speed_mps),
        "MPC_XY_VEL_MAX": Param(p.max_speed_mps),
        "MPC_TKO_SPEED": Param(p.takeoff_speed_mps),
        "MPC_LAND_SPEED": Param(p.land_speed_mps),
        "COM_DISARM_LAND": Param(p.disarm_after_land_s),
        "COM_DISARM_PRFLT": Param(p.disarm_preflight_s),
        "COM_OF_LOSS_T": Param(p.offboard_loss_s),
        "MPC_TKO_RAMP_T": Param(p.takeoff_delay_s),
        "MPC_ACC_HOR": Param(p.accel_mps2),
        "MPC_LAND_ALT1": Param(p.land_alt1_m or 0.0),  # 0: no slowing above MPC_LAND_ALT2
        "MPC_YAWRAUTO_MAX": Param(p.yaw_rate_dps),
        "LNDMC_TRIG_TIME": Param(p.land_detect_s),
        "NAV_DLL_ACT": Param(0, mav.MAV_PARAM_TYPE_INT32),
    }


def param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode(errors="replace")
    return raw.rstrip("\x00")
