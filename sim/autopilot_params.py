"""The autopilot parameters that tune the simulated vehicle model (sim/vehicle.py), by
autopilot: a ground station's PARAM_SET (sim/mavlink_endpoint.py), `fleet sim --param`
and the built-in sim's URL (`sim://?MPC_LAND_SPEED=1.2`) change how the vehicle flies
as the real autopilot's would. No MAVLink here: the agent's built-in sim uses it."""

from __future__ import annotations

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


def check(model: Model, name: str, value: float) -> None:
    """ValueError for a value of parameter `name` the vehicle cannot fly with: a speed
    that is not above 0 (the vehicle would never get there)."""
    field, _ = model[name]
    if field.endswith("_mps") and not value > 0:
        raise ValueError(f"{name} must be above 0, not {value:g}")


def tune(vehicle: Vehicle, model: Model, name: str, value: float) -> None:
    """Set the vehicle model's setting that parameter `name` of `model` stands for
    (ValueError as `check`)."""
    check(model, name, value)
    field, unit = model[name]
    setattr(vehicle.params, field, value * unit)
    if field == "cruise_speed_mps":
        vehicle.cruise_speed = value * unit
