"""The simulator's ArduCopter personality (sim/ardupilot.py) against what a real
ArduCopter 4.5.7 SITL did (shared/notes/ardupilot-facts.md), as a bare ground station
sees it: the commands go over MAVLink, the vehicle model is stepped here (fast time)."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
from pymavlink.dialects.v20 import common as mav2

from dronefleet.sim import ardupilot
from dronefleet.sim.mavlink_endpoint import MavlinkVehicle
from tests.mavlink_gcs import Gcs, answering_autopilot

SPAWN = (40.633490, -8.660815, 8.2)


@pytest.fixture
async def copter() -> AsyncIterator[tuple[MavlinkVehicle, Gcs]]:
    """One simulated ArduCopter answering a ground station; nobody steps it but the test."""
    async with answering_autopilot("ardupilot", SPAWN) as pair:
        yield pair


async def command(gcs: Gcs, cmd: int, *params: float) -> tuple[int, list[str]]:
    """A COMMAND_LONG: its ACK's result and the status texts sent with it."""
    values = [*params, *[0.0] * (7 - len(params))]
    start = len(gcs.got.items)
    ack = await gcs.ask(gcs.mav.command_long_encode(1, 1, cmd, 0, *values), "COMMAND_ACK")
    assert ack.command == cmd
    texts = [m.text for m in gcs.got.items[start:] if m.get_type() == "STATUSTEXT"]
    return ack.result, texts


async def set_mode(gcs: Gcs, mode: int) -> int:
    return (await command(gcs, mav2.MAV_CMD_DO_SET_MODE, 1, mode))[0]


def mode(endpoint: MavlinkVehicle) -> int:
    return endpoint.heartbeat().custom_mode


def fly_for(endpoint: MavlinkVehicle, seconds: float, step_s: float = 0.05) -> None:
    for _ in range(round(seconds / step_s)):
        endpoint.vehicle.step(step_s)


ACCEPTED, FAILED = mav2.MAV_RESULT_ACCEPTED, mav2.MAV_RESULT_FAILED


async def hovering(endpoint: MavlinkVehicle, gcs: Gcs, alt_m: float = 5) -> None:
    """GUIDED, armed, taken off to `alt_m` and there."""
    for cmd, params in ((mav2.MAV_CMD_DO_SET_MODE, (1, ardupilot.GUIDED)), (mav2.MAV_CMD_COMPONENT_ARM_DISARM, (1,)),
                        (mav2.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, alt_m))):
        assert (await command(gcs, cmd, *params))[0] == ACCEPTED
    fly_for(endpoint, alt_m / 1.1 + 3)


async def test_it_says_ardupilot_and_streams_nothing_but_its_heartbeat_until_asked(copter) -> None:
    endpoint, gcs = copter
    beat = endpoint.heartbeat()
    assert (beat.autopilot, beat.custom_mode) == (mav2.MAV_AUTOPILOT_ARDUPILOTMEGA, ardupilot.STABILIZE)
    assert {msg_id for msg_id, period in endpoint.periods.items() if period > 0} == set(ardupilot.STREAMS)
    result, _ = await command(gcs, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 100_000)
    assert result == ACCEPTED and endpoint.periods[mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == pytest.approx(0.1)


async def test_arming_is_refused_in_brake_and_rtl_and_works_from_guided(copter) -> None:
    endpoint, gcs = copter
    for refusing, name in ((ardupilot.BRAKE, "BRAKE"), (ardupilot.RTL, "RTL"), (ardupilot.LAND, "LAND")):
        assert await set_mode(gcs, refusing) == ACCEPTED
        result, texts = await command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert result == FAILED and texts == [f"Arm: {name} mode not armable"] and not endpoint.vehicle.armed
    assert await set_mode(gcs, ardupilot.GUIDED) == ACCEPTED
    assert (await command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1))[0] == ACCEPTED
    assert endpoint.vehicle.armed and mode(endpoint) == ardupilot.GUIDED


async def test_a_takeoff_climbs_in_guided_and_stays_there_then_land_disarms_and_keeps_its_mode(copter) -> None:
    endpoint, gcs = copter
    assert await set_mode(gcs, ardupilot.GUIDED) == ACCEPTED
    assert (await command(gcs, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10))[0] == FAILED  # disarmed
    assert mode(endpoint) == ardupilot.GUIDED  # left where the client switched it
    assert (await command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1))[0] == ACCEPTED
    assert (await command(gcs, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10))[0] == ACCEPTED  # param7: above home
    fly_for(endpoint, 5.0)
    assert 3.0 < endpoint.vehicle.rel_alt < 9.0 and mode(endpoint) == ardupilot.GUIDED
    fly_for(endpoint, 10.0)
    assert endpoint.vehicle.rel_alt == pytest.approx(10.0, abs=0.1) and mode(endpoint) == ardupilot.GUIDED
    assert (await command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 0))[0] == FAILED  # in the air
    assert await set_mode(gcs, ardupilot.LAND) == ACCEPTED
    fly_for(endpoint, 15.0)
    assert endpoint.vehicle.in_air  # 0.5 m/s in the last 10 m: about 20 s
    fly_for(endpoint, 8.0)
    assert not endpoint.vehicle.armed and mode(endpoint) == ardupilot.LAND


@pytest.mark.parametrize("rtl_alt_m", [8.0, 25.0])
async def test_rtl_climbs_to_the_rtl_alt_it_was_set_to(copter, rtl_alt_m: float) -> None:
    """RTL_ALT set by a client (MAVSDK's set_return_to_launch_altitude, the agent's
    return altitude) is where RTL climbs to, below the 15 m default as above it."""
    endpoint, gcs = copter
    m = gcs.mav
    param = await gcs.ask(m.param_set_encode(1, 1, b"RTL_ALT", rtl_alt_m * 100, mav2.MAV_PARAM_TYPE_INT32), "PARAM_VALUE")
    assert param.param_value == rtl_alt_m * 100
    assert await set_mode(gcs, ardupilot.GUIDED) == ACCEPTED
    assert (await command(gcs, mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1))[0] == ACCEPTED
    assert (await command(gcs, mav2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5))[0] == ACCEPTED
    fly_for(endpoint, 10.0)
    assert await set_mode(gcs, ardupilot.RTL) == ACCEPTED
    highest = 0.0
    for _ in range(200):
        fly_for(endpoint, 0.1)
        highest = max(highest, endpoint.vehicle.rel_alt)
    assert highest == pytest.approx(max(rtl_alt_m, 5.0), abs=0.3)


async def test_hold_is_brake_where_speed_changes_fail_and_a_heading_is_condition_yaw(copter) -> None:
    endpoint, gcs = copter
    await hovering(endpoint, gcs)
    assert (await command(gcs, mav2.MAV_CMD_CONDITION_YAW, 90, 0, 0, 0))[0] == ACCEPTED
    fly_for(endpoint, 3.0)
    assert endpoint.vehicle.heading == pytest.approx(90.0, abs=0.5)
    assert await set_mode(gcs, ardupilot.BRAKE) == ACCEPTED
    assert (await command(gcs, mav2.MAV_CMD_DO_CHANGE_SPEED, 1, 3, -1))[0] == FAILED
    assert (await command(gcs, mav2.MAV_CMD_CONDITION_YAW, 180, 0, 0, 0))[0] == FAILED  # not in GUIDED
    assert mode(endpoint) == ardupilot.BRAKE


async def test_a_pilots_radio_and_a_failsafe_show_as_ardupilot_modes(copter) -> None:
    endpoint, gcs = copter
    await hovering(endpoint, gcs)
    endpoint.vehicle.inject_manual(True)
    assert mode(endpoint) == ardupilot.POSHOLD
    endpoint.vehicle.inject_manual(False)
    assert mode(endpoint) == ardupilot.LOITER
    endpoint.vehicle.inject_battery(0.05)
    fly_for(endpoint, 0.5)
    assert mode(endpoint) == ardupilot.RTL


async def test_mission_item_0_is_home_and_integers_travel_cast(copter) -> None:
    endpoint, gcs = copter
    m, mission = gcs.mav, mav2.MAV_MISSION_TYPE_MISSION
    await gcs.ask(m.mission_count_encode(1, 1, 2, mission), "MISSION_REQUEST")
    for seq, lat in ((0, 40.7), (1, 40.6340)):
        item = m.mission_item_int_encode(1, 1, seq, mav2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav2.MAV_CMD_NAV_WAYPOINT,
                                         0, 1, 0, 0, 0, 0, round(lat * 1e7), round(-8.66 * 1e7), 15, mission)
        reply = await gcs.ask(item, "MISSION_ACK" if seq == 1 else "MISSION_REQUEST_INT")
    assert reply.type == mav2.MAV_MISSION_ACCEPTED
    home, second = endpoint.missions.plans[mission]
    assert (home.x, home.y, home.z) == pytest.approx(SPAWN)  # the uploaded item 0 (40.7) was replaced
    assert second.x == pytest.approx(40.6340)
    param = await gcs.ask(m.param_request_read_encode(1, 1, b"RTL_ALT", -1), "PARAM_VALUE")
    assert (param.param_type, param.param_value) == (mav2.MAV_PARAM_TYPE_INT32, 1500.0)  # cm, the value as a float
    param = await gcs.ask(m.param_set_encode(1, 1, b"RTL_ALT", 2500.0, mav2.MAV_PARAM_TYPE_INT32), "PARAM_VALUE")
    assert param.param_value == 2500.0 and endpoint.params["RTL_ALT"].value == 2500.0
