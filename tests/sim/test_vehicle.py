"""The vehicle model on its own, stepped in virtual time (no event loop)."""

from __future__ import annotations

import pytest

from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.autopilot_params import timing_of
from dronefleet.sim.vehicle import Vehicle
from dronefleet.sim.world import World

LAT, LON, GROUND = 40.633490, -8.660815, 8.2
DT = 0.05


def fly(v: Vehicle, seconds: float, until=None) -> float:
    """Step up to `seconds`; return the time taken when `until(v)` became true."""
    t = 0.0
    while t < seconds:
        v.step(DT)
        t += DT
        if until is not None and until(v):
            return t
    if until is not None:
        raise AssertionError(f"condition not reached in {seconds} s (mode {v.mode}, alt {v.rel_alt:.2f})")
    return t


def airborne(alt: float = 5.0) -> Vehicle:
    v = Vehicle(LAT, LON, GROUND)
    assert v.arm() is None
    assert v.takeoff(alt) is None
    fly(v, 30, lambda v: v.mode == "hold")
    return v


def test_takeoff_climbs_at_takeoff_speed_then_holds() -> None:
    v = Vehicle(LAT, LON, GROUND)
    assert v.takeoff(5) == "takeoff denied: disarmed"
    assert v.arm() is None
    assert v.takeoff(5) is None
    assert v.mode == "takeoff" and v.landed_state == "taking_off"
    took = fly(v, 30, lambda v: v.mode == "hold")
    assert took == pytest.approx(5 / 1.5, abs=0.2)
    assert v.rel_alt == pytest.approx(5.0, abs=1e-6)
    assert v.landed_state == "in_air"


def test_goto_respects_speed_and_keeps_target_altitude() -> None:
    v = airborne(5)
    lat, lon = destination(LAT, LON, 30, 0)
    assert v.goto(lat, lon, GROUND + 5, None, 5.0) is None
    took = fly(v, 30, lambda v: distance_m(v.position().lat, v.position().lon, lat, lon) < 0.01)
    assert took == pytest.approx(6.0, abs=0.2)
    assert v.position().alt == pytest.approx(GROUND + 5)
    assert v.speed() == pytest.approx(5.0)


def test_goto_on_the_ground_is_denied() -> None:
    v = Vehicle(LAT, LON, GROUND)
    v.arm()
    assert v.goto(LAT, LON, GROUND + 5) == "reposition denied: on ground"


def test_land_then_automatic_disarm_after_two_seconds() -> None:
    v = airborne(8)
    assert v.land() is None
    took = fly(v, 60, lambda v: v.landed_state == "on_ground")
    # 3 m at 1.5 m/s above 5 m, then 5 m at 0.7 m/s
    assert took == pytest.approx(3 / 1.5 + 5 / 0.7, abs=0.3)
    assert v.armed
    disarm_after = fly(v, 5, lambda v: not v.armed)
    assert disarm_after == pytest.approx(2.0, abs=0.1)
    assert "Disarmed by landing" in v.events


def test_return_climbs_to_at_least_ten_metres_flies_home_and_lands() -> None:
    v = airborne(5)
    lat, lon = destination(LAT, LON, 40, 90)
    v.goto(lat, lon, GROUND + 5)
    fly(v, 30, lambda v: v.speed() == 0 and v.vn == 0 and abs(v.east - 40) < 0.01)
    assert v.return_to_launch(3) is None
    peak = 0.0
    def landed(v: Vehicle) -> bool:
        nonlocal peak
        peak = max(peak, v.rel_alt)
        return v.landed_state == "on_ground"
    fly(v, 120, landed)
    assert peak == pytest.approx(10.0, abs=0.01)  # max(3, 10 m minimum)
    assert distance_m(v.position().lat, v.position().lon, LAT, LON) < 0.01
    disarm_after = fly(v, 5, lambda v: not v.armed)
    assert disarm_after == pytest.approx(2.0, abs=0.1)


def test_preflight_auto_disarm_when_no_takeoff() -> None:
    v = Vehicle(LAT, LON, GROUND)
    v.arm()
    took = fly(v, 20, lambda v: not v.armed)
    assert took == pytest.approx(10.0, abs=0.1)


def test_battery_drains_to_floor_and_refills_on_disarm() -> None:
    v = airborne(5)
    fly(v, 400)
    assert v.battery == pytest.approx(v.params.battery_floor)
    v.land()
    fly(v, 60, lambda v: not v.armed)
    assert v.battery == 1.0


def test_low_battery_triggers_automatic_return() -> None:
    v = airborne(5)
    v.inject_battery(0.05)
    v.step(DT)
    assert v.mode == "return_to_launch"


def test_offboard_needs_fresh_setpoints_and_falls_back_to_hold() -> None:
    v = airborne(5)
    assert v.start_offboard() == "offboard denied: no setpoint streaming"
    v.set_setpoint("velocity_ned", north=2.0, east=0.0, down=0.0, yaw=None)
    assert v.start_offboard() is None
    fly(v, 0.9)
    assert v.mode == "offboard" and v.vn == pytest.approx(2.0)
    fly(v, 0.3)  # setpoints stopped 1.2 s ago
    assert v.mode == "hold"


def test_velocity_body_moves_relative_to_heading() -> None:
    v = airborne(5)
    v.heading = 90.0
    v.set_setpoint("velocity_body", forward=1.0, right=0.0, down=0.0, yaw=0.0)
    v.start_offboard()
    for _ in range(20):
        v.set_setpoint("velocity_body", forward=1.0, right=0.0, down=0.0, yaw=0.0)
        fly(v, 0.1)
    assert v.east == pytest.approx(2.0, abs=0.06) and abs(v.north) < 1e-6


def test_manual_takeover_holds_and_release_returns_to_hold() -> None:
    v = airborne(5)
    v.inject_manual(True)
    assert v.mode == "posctl"
    assert v.takeoff(3) is not None
    v.inject_manual(False)
    assert v.mode == "hold"


def test_health_failure_and_gps_loss_deny_arming() -> None:
    v = Vehicle(LAT, LON, GROUND)
    v.inject_health_failure("accelerometer")
    assert "accelerometer" in (v.arm() or "")
    v.inject_health_failure()
    v.inject_gps("no_fix")
    assert "GPS" in (v.arm() or "")
    assert v.gps().satellites == 0


def test_goto_yaw_turns_at_the_yaw_rate() -> None:
    v = airborne(5)
    pos = v.position()
    v.goto(pos.lat, pos.lon, pos.alt, 90.0)
    took = fly(v, 5, lambda v: abs(v.heading - 90.0) < 1e-6)
    assert took == pytest.approx(1.0, abs=0.06)


def test_px4_timing_starts_late_speeds_up_and_brakes_slows_its_descent_and_detects_landing_late() -> None:
    """A make's timing (autopilot_params.TIMING: PX4's, fitted to real SITL flights): the
    climb starts `takeoff_delay_s` after the command; no leg changes speed faster than
    `accel_mps2`, and each ends at rest; the landing is detected `land_detect_s` after
    touchdown, and the whole profile matches what PX4 SITL flew within 10 %."""
    timing = timing_of("px4")
    v = Vehicle(LAT, LON, GROUND, World().params("px4"))
    v.arm()
    v.takeoff(15)
    fly(v, timing["takeoff_delay_s"] - DT)
    assert v.rel_alt == 0.0 and v.landed_state == "taking_off"
    assert fly(v, 60, lambda v: v.rel_alt >= 14.5) + timing["takeoff_delay_s"] == pytest.approx(16.1, rel=0.1)
    fly(v, 30, lambda v: v.mode == "hold")
    lat, lon = destination(LAT, LON, 60, 0)
    v.goto(lat, lon, GROUND + 15)
    speeds, t = [0.0], 0.0
    while distance_m(v.position().lat, v.position().lon, lat, lon) > 1e-3:
        v.step(DT)
        t += DT
        speeds.append(v.speed())
        assert t < 60
    assert max(abs(b - a) for a, b in zip(speeds, speeds[1:], strict=False)) <= timing["accel_mps2"] * DT + 1e-9
    assert max(speeds) == pytest.approx(5.0) and speeds[-1] < 0.5
    v.land()
    touched = fly(v, 60, lambda v: v.rel_alt <= 1e-3)
    landed = fly(v, 60, lambda v: v.landed_state == "on_ground")
    assert landed == pytest.approx(timing["land_detect_s"], abs=2 * DT)
    assert touched + landed == pytest.approx(20.4, rel=0.1)
