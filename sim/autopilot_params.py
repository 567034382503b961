"""The autopilot parameters that tune the simulated vehicle model (sim/vehicle.py), by
autopilot: a ground station's PARAM_SET (sim/mavlink_endpoint.py), `fleet sim --param`
and the built-in sim's URL (`sim://?MPC_LAND_SPEED=1.2`) change how the vehicle flies
as the real autopilot's would. No MAVLink here: the agent's built-in sim uses it."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from dronefleet.sim.vehicle import Vehicle

# name → (the VehicleParams field it sets, the field's units per parameter unit)
Model = dict[str, tuple[str, float]]

PX4: Model = {
    "MIS_TAKEOFF_ALT": ("takeoff_alt_m", 1.0),
    "RTL_RETURN_ALT": ("rtl_min_alt_m", 1.0),
    "MPC_XY_CRUISE": ("cruise_speed_mps", 1.0),
    "MPC_XY_VEL_MAX": ("max_speed_mps", 1.0),
    "MPC_TKO_SPEED": ("takeoff_speed_mps", 1.0),
    "MPC_LAND_SPEED": ("land_speed_mps", 1.0),
    "COM_DISARM_LAND": ("disarm_after_land_s", 1.0),
    "COM_DISARM_PRFLT": ("disarm_preflight_s", 1.0),
    "COM_OF_LOSS_T": ("offboard_loss_s", 1.0),
    # How it gets going and comes to rest (TIMING below); 0 turns each off. The model's
    # start is one delay where PX4 has COM_SPOOLUP_TIME, then MPC_TKO_RAMP_T: it is set
    # by the second, which reads the whole delay. LNDMC_TRIG_TIME likewise reads the
    # whole time from touchdown to a detected landing.
    "MPC_TKO_RAMP_T": ("takeoff_delay_s", 1.0),
    "MPC_ACC_HOR": ("accel_mps2", 1.0),
    "MPC_LAND_ALT1": ("land_alt1_m", 1.0),
    "MPC_YAWRAUTO_MAX": ("yaw_rate_dps", 1.0),
    "LNDMC_TRIG_TIME": ("land_detect_s", 1.0),
}

# ArduCopter's, in centimetres and cm/s: LAND_SPEED is the speed below LAND_ALT_LOW
# (10 m), WPNAV_SPEED_DN the descent above it.
ARDUPILOT: Model = {
    "RTL_ALT": ("rtl_min_alt_m", 0.01),
    "WPNAV_SPEED": ("cruise_speed_mps", 0.01),
    "WPNAV_SPEED_DN": ("descent_speed_mps", 0.01),
    "LAND_SPEED": ("land_speed_mps", 0.01),
    "DISARM_DELAY": ("disarm_after_land_s", 1.0),
}

BY_AUTOPILOT: dict[str, Model] = {"px4": PX4, "ardupilot": ARDUPILOT}

# How a make gets going and comes to rest, at its default parameters, where the vehicle
# model is otherwise instant (VehicleParams). Fitted to PX4 1.16 SITL (SIH quad) flown
# through the agent's adapter (docs/guides/real-hardware.md): a takeoff to 15 m passed
# 14.5 m after 16.1 s and one to 5 m ended at 9.1 s (spool-up, MPC_TKO_RAMP_T, then about
# 1.4 m/s: a 6 s start at 1.5 m/s fits both); a 60-m leg came within 1 m after 16.5 s and
# a 10-m one ended after 6.4 s (1 m/s² each way at 5 m/s fits both); the descent slowed
# from 1.5 m/s at MPC_LAND_ALT1 (10 m) to 0.7 m/s at 5 m, and the landing was detected
# about 5 s after touchdown; in the mapping example its turns of 90° and 180° where it
# stood took 3.5 and 5.4 s (MPC_YAWRAUTO_MAX 45°/s, then settling: 38°/s fits both to
# within 0.6 s). `fleet sim` flies each vehicle with its make's, and the ground's
# predictions each drone.
@dataclass(frozen=True)
class Timing:
    takeoff_delay_s: float
    accel_mps2: float
    land_alt1_m: float | None
    land_detect_s: float
    yaw_rate_dps: float


TIMING: dict[str, Timing] = {
    "px4": Timing(takeoff_delay_s=6.0, accel_mps2=1.0, land_alt1_m=10.0, land_detect_s=5.0,
                  yaw_rate_dps=38.0),
}


# PX4's timing parameters turned off: its vehicles get going and come to rest at once, as
# the built-in simulator's do (the radio demo, and tests that fly for what else they show).
BRISK_PX4: dict[str, float] = {"MPC_TKO_RAMP_T": 0.0, "MPC_ACC_HOR": 0.0, "MPC_LAND_ALT1": 0.0, "LNDMC_TRIG_TIME": 0.0,
                               "MPC_YAWRAUTO_MAX": 90.0}


def timing_of(autopilot: str | None) -> dict[str, Any]:
    """VehicleParams fields for how `autopilot` gets going and comes to rest ({}: instant)."""
    timing = TIMING.get(autopilot or "")
    return asdict(timing) if timing is not None else {}


def check(model: Model, name: str, value: float) -> None:
    """ValueError for a value of parameter `name` the vehicle cannot fly with: a speed or
    turn rate that is not above 0 (the vehicle would never get there), a time, height or
    acceleration below 0."""
    field, _ = model[name]
    if field.endswith(("_mps", "_dps")) and not value > 0:
        raise ValueError(f"{name} must be above 0, not {value:g}")
    if not value >= 0:
        raise ValueError(f"{name} must not be below 0, not {value:g}")


def tune(vehicle: Vehicle, model: Model, name: str, value: float) -> None:
    """Set the vehicle model's setting that parameter `name` of `model` stands for
    (ValueError as `check`)."""
    check(model, name, value)
    field, unit = model[name]
    setattr(vehicle.params, field, value * unit)
    if field == "cruise_speed_mps":
        vehicle.cruise_speed = value * unit
