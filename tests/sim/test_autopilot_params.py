"""Parameters that tune the simulated vehicle (sim/autopilot_params.py), set as a ground
station sets them (PARAM_SET over MAVLink), by `fleet sim --param` and in the built-in
sim's URL: the vehicle then flies as the real autopilot would with them."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
from pymavlink.dialects.v20 import common as mav2

from dronefleet.agent.fc_sim import parse_sim_url
from dronefleet.schemas.errors import ConfigError
from dronefleet.sim import ardupilot
from dronefleet.sim.autopilot_params import TIMING
from dronefleet.sim.fleet_sim import check_params
from dronefleet.sim.mavlink_endpoint import MavlinkVehicle
from dronefleet.sim.vehicle import Vehicle
from dronefleet.sim.world import load_world
from tests.mavlink_gcs import Gcs, answering_autopilot

SPAWN = (40.633490, -8.660815, 8.2)
ACCEPTED = mav2.MAV_RESULT_ACCEPTED


@pytest.fixture(params=["px4", "ardupilot"])
async def vehicle(request: pytest.FixtureRequest) -> AsyncIterator[tuple[MavlinkVehicle, Gcs]]:
    """One simulated autopilot of each kind answering a ground station."""
    async with answering_autopilot(request.param, SPAWN) as pair:
        yield pair


async def command(gcs: Gcs, cmd: int, *params: float) -> int:
    values = [*params, *[0.0] * (7 - len(params))]
    ack = await gcs.ask(gcs.mav.command_long_encode(1, 1, cmd, 0, *values), "COMMAND_ACK")
    return int(ack.result)


def seconds_to_land(endpoint: MavlinkVehicle, step_s: float = 0.05) -> float:
    flown = 0.0
    while endpoint.vehicle.in_air:
        endpoint.vehicle.step(step_s)
        flown += step_s
        assert flown < 120, "still in the air after 2 minutes"
    return flown


# (autopilot) → its landing-speed parameter and a value, in the parameter's unit and in m/s
LANDING = {"px4": ("MPC_LAND_SPEED", 1.4, 1.4), "ardupilot": ("LAND_SPEED", 140, 1.4)}


async def test_a_landing_speed_set_over_mavlink_is_the_speed_the_vehicle_lands_at(vehicle) -> None:
    endpoint, gcs = vehicle
    autopilot = "px4" if endpoint.copter is None else "ardupilot"
    name, value, mps = LANDING[autopilot]
    kind = endpoint.params[name].kind
    set_to = gcs.mav.param_set_encode(1, 1, name.encode(), float(value), kind)
    assert (await gcs.ask(set_to, "PARAM_VALUE")).param_value == pytest.approx(value)
    if autopilot == "ardupilot":  # takes off from GUIDED to param 7, metres above home
        assert await command(gcs, mav2.MAV_CMD_DO_SET_MODE, 1, ardupilot.GUIDED) == ACCEPTED
        up = 4.0
    else:  # to MIS_TAKEOFF_ALT, set here too
        takeoff_alt = gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 4.0, mav2.MAV_PARAM_TYPE_REAL32)
        assert (await gcs.ask(takeoff_alt, "PARAM_VALUE")).param_value == 4.0
        up = float("nan")
    assert await command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
    assert await command(gcs, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, float("nan"), float("nan"), up) == ACCEPTED
    for _ in range(400):
        endpoint.vehicle.step(0.05)
    assert endpoint.vehicle.rel_alt == pytest.approx(4.0, abs=0.2)
    assert await command(gcs, mav2.MAV_CMD_NAV_LAND) == ACCEPTED
    # 4 m at the set speed (ArduCopter lands at LAND_SPEED below 10 m), give or take the
    # last half metre's slowing and the touchdown
    assert seconds_to_land(endpoint) == pytest.approx(4.0 / mps, abs=1.0)


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_fleet_sims_param_sets_what_the_autopilot_has_and_names_what_none_has(autopilot: str) -> None:
    endpoint = MavlinkVehicle(Vehicle(*SPAWN), 1, [], autopilot=autopilot)
    name, value, mps = LANDING[autopilot]
    endpoint.set_param(name, value)
    assert endpoint.params[name].value == value and endpoint.vehicle.params.land_speed_mps == pytest.approx(mps)
    check_params({name: value}, {autopilot})
    check_params({name: value}, {"px4", "ardupilot"})  # mixed: set where it exists
    other = LANDING["ardupilot" if autopilot == "px4" else "px4"][0]
    with pytest.raises(ConfigError, match=f"--param {other}: no {autopilot} vehicle here has it"):
        check_params({other: 1.0}, {autopilot})


def test_the_built_in_sims_url_takes_px4_parameters() -> None:
    vehicle, _ = parse_sim_url("sim://?lat=40.6&MPC_LAND_SPEED=1.4&MPC_XY_CRUISE=8")
    assert vehicle.params.land_speed_mps == 1.4 and vehicle.cruise_speed == 8.0
    with pytest.raises(ConfigError, match="LAND_SPEED"):
        parse_sim_url("sim://?LAND_SPEED=140")


async def test_a_speed_of_zero_set_over_mavlink_is_refused_and_read_back_unchanged(vehicle) -> None:
    endpoint, gcs = vehicle
    name = LANDING["px4" if endpoint.copter is None else "ardupilot"][0]
    before = endpoint.params[name].value
    set_to = gcs.mav.param_set_encode(1, 1, name.encode(), 0.0, endpoint.params[name].kind)
    assert (await gcs.ask(set_to, "PARAM_VALUE")).param_value == pytest.approx(before)
    assert endpoint.vehicle.params.land_speed_mps > 0


def climb_starts_after_s(vehicle: Vehicle, step_s: float = 0.05) -> float:
    waited = 0.0
    while vehicle.rel_alt < 0.5:
        vehicle.step(step_s)
        waited += step_s
        assert waited < 60, "no climb within a minute"
    return waited


def test_fleet_sims_px4_starts_a_takeoff_as_px4_does_until_its_parameter_says_otherwise() -> None:
    """A `fleet sim` PX4 vehicle carries PX4's start (autopilot_params.TIMING), shown as
    its parameter and flown; an ArduCopter one flies the instant model."""
    world = load_world(None)
    spec = world.spawn(1)[0]
    delay = TIMING["px4"].takeoff_delay_s

    def px4(sysid: int) -> MavlinkVehicle:
        endpoint = MavlinkVehicle(world.vehicle(spec, "px4"), sysid, [], autopilot="px4")
        endpoint.vehicle.arm()
        return endpoint

    as_px4 = px4(1)
    assert as_px4.params["MPC_TKO_RAMP_T"].value == delay
    as_px4.vehicle.takeoff(5.0)
    # The climb itself, to half a metre at MPC_TKO_SPEED, takes well under a second.
    assert climb_starts_after_s(as_px4.vehicle) == pytest.approx(delay, abs=1.0)
    brisk = px4(2)
    brisk.set_param("MPC_TKO_RAMP_T", 0.0)
    brisk.vehicle.takeoff(5.0)
    assert climb_starts_after_s(brisk.vehicle) < 1.0
    assert world.vehicle(spec, "ardupilot").params.takeoff_delay_s == 0.0
