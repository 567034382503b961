"""The MAVLink simulator and the MAVSDK adapter together: several vehicles, faults,
an independent MAVLink client, and start-up/shutdown behaviour of the agent."""

from __future__ import annotations

import asyncio
import signal
import struct
import subprocess
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav2

from dronefleet.agent.fc_mavsdk import REST_RATE_HZ, MavsdkFlightController
from dronefleet.agent.fc_port import FcRejected
from dronefleet.agent.fc_sim import SimFlightController
from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.faults import send_fault
from dronefleet.sim.mavlink_endpoint import MavlinkVehicle
from dronefleet.sim.vehicle import Vehicle
from tests.harness import AgentProcess, Operator, SimProcess, at, fleet_command
from tests.mavlink_gcs import Gcs
from tests.ports import free_udp_base
from tests.waiting import until

pytestmark = pytest.mark.integration


async def airborne(op: Operator, alt: float = 5) -> None:
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    await op.expect(await op.accepted("arm"), "success", 10)
    await op.expect(await op.accepted("takeoff", alt=alt), "finish", 30)


@pytest.mark.slow(37)
async def test_three_vehicles_from_fleet_sim_agents_fly_concurrently(endpoint: str, client: ZenohBus, tmp_path: Path) -> None:
    config = tmp_path / "agent.yml"
    config.write_text("telemetry_rate_ms: 200\n")
    sim = SimProcess(tmp_path, n=3, extra_args=["--agents", "--connect", endpoint, "--agent-config", str(config)])
    try:
        ops = [Operator(client, f"drone0{i}") for i in (1, 2, 3)]

        airborne_at: list[int] = []  # each vehicle's goto start, on its agent's clock (ms)
        landed_at: list[int] = []

        async def fly(op: Operator, metres: float) -> tuple[float, float]:
            await airborne(op, alt=3 + metres / 10)
            here = at(op.last)
            lat, lon = destination(here.lat, here.lon, metres, 0)
            goto = await op.accepted("goto", lat=lat, lon=lon, yaw=None)
            airborne_at.append((await op.expect(goto, "start", 40)).timestamp)
            await op.expect(goto, "finish", 40)
            landed_at.append((await op.expect(await op.accepted("land"), "finish", 40)).timestamp)
            return lat, lon

        targets = await asyncio.gather(*(fly(op, m) for op, m in zip(ops, (20, 25, 30), strict=True)))
        for op, (lat, lon) in zip(ops, targets, strict=True):
            t = await op.next_telemetry()
            assert t.landed_state == "on_ground"
            assert distance_m(at(t).lat, at(t).lon, lat, lon) < 1.0
        # Concurrent, not one after the other: all three were flying their gotos before
        # the first one landed (order on the agents' own timestamps, not a speed).
        assert max(airborne_at) < min(landed_at), (airborne_at, landed_at)
        homes = {round(op.last.home.lon, 6) for op in ops if op.last.home is not None}
        assert len(homes) == 3  # three distinct vehicles, not one System seen thrice
    finally:
        sim.stop()
    assert sim.proc is not None and sim.proc.returncode == 0
    assert "agent drone03 started" in sim.log.read_text()


@pytest.fixture
def sim_and_agent(agents: Callable[..., AgentProcess], tmp_path: Path) -> Iterator[tuple[SimProcess, AgentProcess]]:
    sim = SimProcess(tmp_path)
    agent = agents("drone01", fc=sim.fc_url())
    yield sim, agent
    sim.stop(signal.SIGKILL)


async def test_simulator_killed_mid_flight_disconnects_then_reconnects(sim_and_agent, operator) -> None:
    sim, _ = sim_and_agent
    op = operator("drone01")
    await airborne(op)  # connected: its first `connect` may have gone out before this operator listened
    sim.stop(signal.SIGKILL)
    await op.system("disconnect", 15)  # a liveness deadline: the agent notices the silence
    after_disconnect = len(op.status.items)
    sim.start()
    await op.status.wait_for(
        lambda s: getattr(s, "component", None) == "system" and s.state == "connect", 15, "reconnect",
        start=after_disconnect,
    )
    # The restarted vehicle is on the ground: the agent sees it again.
    await op.next_telemetry(lambda t: t.landed_state == "on_ground", 10, "telemetry of the restarted vehicle")


async def test_rc_takeover_and_release(sim_and_agent, operator) -> None:
    sim, _ = sim_and_agent
    op = operator("drone01")
    await airborne(op)
    here = at(op.last)
    lat, lon = destination(here.lat, here.lon, 200, 0)
    goto = await op.accepted("goto", lat=lat, lon=lon)
    await op.expect(goto, "start", 10)
    assert (await send_fault("drone01", "rc_takeover", None, sim.control))["ok"]
    await op.system("start_manual", 5)
    cancelled = await op.expect(goto, "cancel", 5)
    assert cancelled.reason == "manual control"
    assert (await send_fault("drone01", "rc_release", None, sim.control))["ok"]
    await op.system("stop_manual", 5)


@pytest.mark.slow(33)
async def test_low_battery_rtl_is_reported_then_landing_auto_disarms(sim_and_agent, operator) -> None:
    sim, _ = sim_and_agent
    op = operator("drone01")
    await airborne(op)
    assert (await send_fault("drone01", "low_battery", "0.08", sim.control))["ok"]
    await op.system("return", 5)
    await op.next_telemetry(lambda t: t.landed_state == "on_ground", 60, "landing after the automatic return")
    await op.system("disarm", 10)


async def test_an_independent_mavlink_client_reads_the_simulator(tmp_path: Path) -> None:
    gcs_port = free_udp_base(1)
    sim = SimProcess(tmp_path, extra_args=["--output", f"127.0.0.1:{gcs_port}"])
    link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
    try:
        heartbeat = await asyncio.to_thread(link.recv_match, type="HEARTBEAT", blocking=True, timeout=10)
        assert heartbeat is not None, "no HEARTBEAT"
        assert heartbeat.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
        assert heartbeat.custom_mode == 0x03040000  # AUTO.LOITER (hold)
        position = await asyncio.to_thread(link.recv_match, type="GLOBAL_POSITION_INT", blocking=True, timeout=5)
        assert position is not None
        assert position.lat / 1e7 == pytest.approx(40.633490, abs=1e-6)
        assert position.relative_alt == 0
        # It answers requests from this client too.
        link.mav.param_request_read_send(link.target_system or 1, 1, b"MIS_TAKEOFF_ALT", -1)
        param = await asyncio.to_thread(link.recv_match, type="PARAM_VALUE", blocking=True, timeout=5)
        assert param is not None and param.param_id == "MIS_TAKEOFF_ALT"
    finally:
        link.close()
        sim.stop()


def test_agent_exits_clearly_when_the_flight_controller_is_unreachable() -> None:
    port = free_udp_base(1)
    result = subprocess.run(  # a hang fails here (TimeoutExpired); how fast is not this test's business
        fleet_command("agent", "--id", "drone01", "--fc", f"udpin://127.0.0.1:{port}", "--connect", "tcp/127.0.0.1:1"),
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 1
    assert f"no autopilot heartbeat on udpin://127.0.0.1:{port}" in result.stderr


async def test_agent_shuts_down_cleanly_on_sigterm(sim_and_agent, operator) -> None:
    _, agent = sim_and_agent
    op = operator("drone01")
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    assert agent.stop(signal.SIGTERM, timeout_s=10) == 0
    assert "Traceback" not in agent.output()


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("udp://:14540", "udpin://0.0.0.0:14540"),
        ("udp://0.0.0.0:14541", "udpin://0.0.0.0:14541"),
        ("udp://192.168.1.5:14540", "udpout://192.168.1.5:14540"),
        ("udpin://127.0.0.1:14540", "udpin://127.0.0.1:14540"),
        ("serial:///dev/ttyACM0", "serial:///dev/ttyACM0:57600"),
        ("serial:///dev/ttyTHS1:921600", "serial:///dev/ttyTHS1:921600"),
        ("tcp://10.0.0.2:5760", "tcpout://10.0.0.2:5760"),
    ],
)
def test_flight_controller_urls(url: str, expected: str) -> None:
    from dronefleet.agent.fc_mavsdk import mavsdk_url

    assert mavsdk_url(url) == expected


@pytest.mark.parametrize("url", ["serial:///dev/ttyACM0:fast", "ftp://x", "udp://"])
def test_bad_flight_controller_urls(url: str) -> None:
    from dronefleet.agent.fc_mavsdk import mavsdk_url
    from dronefleet.schemas.errors import ConfigError

    with pytest.raises(ConfigError):
        mavsdk_url(url)


# ----- geofence upload: the mission protocol of the MAVLink simulator ------------------

FENCE = [(40.6345, -8.6612), (40.6345, -8.6590), (40.6325, -8.6590), (40.6325, -8.6612)]
SMALLER_FENCE = [(40.6340, -8.6605), (40.6340, -8.6595), (40.6330, -8.6600)]


def assert_same_polygon(got: list[tuple[float, float]], want: list[tuple[float, float]]) -> None:
    assert len(got) == len(want), got
    for (lat, lon), (want_lat, want_lon) in zip(got, want, strict=True):
        assert abs(lat - want_lat) <= 1e-7 and abs(lon - want_lon) <= 1e-7, (got, want)


@pytest.fixture(params=["px4"])
async def px4(request: pytest.FixtureRequest) -> AsyncIterator[MavlinkVehicle]:
    """One simulated PX4 (or, asked for, ArduCopter) in this process, stepping, sending
    to a free loopback port."""
    port = free_udp_base(1)
    endpoint = MavlinkVehicle(Vehicle(40.633490, -8.660815, 8.2), 1, [("127.0.0.1", port)], autopilot=request.param)
    await endpoint.start(("127.0.0.1", 0))
    stepping = asyncio.get_running_loop().create_task(endpoint.run())
    try:
        yield endpoint
    finally:
        stepping.cancel()
        await asyncio.wait([stepping])
        endpoint.close()


@pytest.fixture
async def mavsdk_fc(px4: MavlinkVehicle) -> AsyncIterator[MavsdkFlightController]:
    """The agent's MAVSDK adapter (real mavsdk 4.x) connected to `px4`."""
    fc = MavsdkFlightController(f"udpin://127.0.0.1:{px4.outputs[0][1]}")
    try:
        await fc.start()
        yield fc
    finally:
        await fc.close()


async def test_mavsdk_uploads_a_geofence_the_simulator_holds_and_a_second_replaces_it(
    px4: MavlinkVehicle, mavsdk_fc: MavsdkFlightController,
) -> None:
    # upload_fence returns on the vehicle's MISSION_ACK, which it sends after storing.
    await mavsdk_fc.upload_fence(FENCE)
    assert_same_polygon(px4.vehicle.fence, FENCE)
    items = px4.missions.plans[mav2.MAV_MISSION_TYPE_FENCE]
    assert [i.command for i in items] == [mav2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4
    assert {i.params[0] for i in items} == {4.0}  # param1: the polygon's vertex count
    # As PX4, the vehicle asked in float messages first; MAVSDK answered UNSUPPORTED and
    # the vehicle switched to MISSION_REQUEST_INT.
    assert px4.missions.int_mode

    await mavsdk_fc.upload_fence(SMALLER_FENCE)
    assert_same_polygon(px4.vehicle.fence, SMALLER_FENCE)
    assert len(px4.missions.plans[mav2.MAV_MISSION_TYPE_FENCE]) == 3
    assert px4.missions.state == "idle"


async def test_a_fence_the_autopilot_cannot_store_is_refused_and_the_old_one_kept(
    px4: MavlinkVehicle, mavsdk_fc: MavsdkFlightController,
) -> None:
    await mavsdk_fc.upload_fence(FENCE)
    too_many = [(40.63 + i * 1e-5, -8.66 + (i % 2) * 1e-5) for i in range(65)]  # PX4 keeps 64 fence items
    with pytest.raises(FcRejected, match="too many geofence items"):
        await mavsdk_fc.upload_fence(too_many)
    with pytest.raises(FcRejected, match="invalid argument"):  # MAVSDK's own check
        await mavsdk_fc.upload_fence(FENCE[:2])
    assert_same_polygon(px4.vehicle.fence, FENCE)


@pytest.mark.parametrize("px4", ["px4", "ardupilot"], indirect=True)
async def test_the_flight_streams_run_at_flight_rates_only_while_armed(
    px4: MavlinkVehicle, mavsdk_fc: MavsdkFlightController,
) -> None:
    """At rest the adapter asks for the position, velocity and attitude streams at
    REST_RATE_HZ (each message is a callback into the agent's loop); armed, at the
    autopilot's flight rates; disarmed again, at rest again."""
    flight = [mav2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav2.MAVLINK_MSG_ID_ATTITUDE]

    def periods() -> list[float]:
        return [round(px4.periods.get(msg_id, 0.0), 3) for msg_id in flight]

    assert periods() == [round(1 / REST_RATE_HZ, 3)] * 3
    await until(lambda: mavsdk_fc.state().health_failures == (), 30, "the autopilot healthy")
    await mavsdk_fc.arm()
    await until(lambda: periods() == [0.1] * 3, 10, f"flight rates once armed (periods {periods()})")
    await mavsdk_fc.disarm()
    await until(lambda: periods() == [round(1 / REST_RATE_HZ, 3)] * 3, 10, f"rest rates once disarmed (periods {periods()})")


async def test_the_builtin_sim_controller_holds_the_fence_like_the_mavlink_one() -> None:
    vehicle = Vehicle(40.633490, -8.660815, 8.2)
    fc = SimFlightController(vehicle, VirtualClock())
    await fc.start()
    try:
        await fc.upload_fence(FENCE)
        assert_same_polygon(vehicle.fence, FENCE)
        await fc.upload_fence(SMALLER_FENCE)
        assert_same_polygon(vehicle.fence, SMALLER_FENCE)
        with pytest.raises(FcRejected, match="invalid argument"):
            await fc.upload_fence(FENCE[:2])
        with pytest.raises(FcRejected, match="too many geofence items"):
            await fc.upload_fence([(40.63 + i * 1e-5, -8.66) for i in range(65)])
        assert_same_polygon(vehicle.fence, SMALLER_FENCE)
        vehicle.connected = False
        with pytest.raises(FcRejected, match="not responding"):
            await fc.upload_fence(FENCE)
    finally:
        await fc.close()


def e7_of_float32(deg: float) -> int:
    """A coordinate sent in a float MISSION_ITEM, as it comes back in a MISSION_ITEM_INT."""
    return round(struct.unpack("<f", struct.pack("<f", deg))[0] * 1e7)


async def test_a_ground_station_uploads_and_downloads_a_mission_and_rally_points(px4: MavlinkVehicle) -> None:
    loop = asyncio.get_running_loop()
    transport, gcs = await loop.create_datagram_endpoint(Gcs, remote_addr=("127.0.0.1", px4.local_port))
    m, MISSION, RALLY = gcs.mav, mav2.MAV_MISSION_TYPE_MISSION, mav2.MAV_MISSION_TYPE_RALLY
    try:
        # Upload in float messages (MISSION_ITEM), as PX4 first asks for them.
        request = await gcs.ask(m.mission_count_encode(1, 1, 2, MISSION), "MISSION_REQUEST")
        assert (request.seq, request.mission_type) == (0, MISSION)
        takeoff = m.mission_item_encode(1, 1, 0, mav2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav2.MAV_CMD_NAV_TAKEOFF,
                                        1, 1, 0, 0, 0, 0, 40.6335, -8.6608, 10, MISSION)
        assert (await gcs.ask(takeoff, "MISSION_REQUEST")).seq == 1
        waypoint = m.mission_item_encode(1, 1, 1, mav2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav2.MAV_CMD_NAV_WAYPOINT,
                                         0, 1, 0, 0, 0, 0, 40.6340, -8.6600, 15, MISSION)
        ack = await gcs.ask(waypoint, "MISSION_ACK")
        assert (ack.type, ack.mission_type) == (mav2.MAV_MISSION_ACCEPTED, MISSION)
        # Download in int messages.
        count = await gcs.ask(m.mission_request_list_encode(1, 1, MISSION), "MISSION_COUNT")
        assert count.count == 2
        first = await gcs.ask(m.mission_request_int_encode(1, 1, 0, MISSION), "MISSION_ITEM_INT")
        assert (first.command, first.frame, first.x, first.y, first.z) == (  # as received: float32 degrees
            mav2.MAV_CMD_NAV_TAKEOFF, mav2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, e7_of_float32(40.6335),
            e7_of_float32(-8.6608), 10)
        second = await gcs.ask(m.mission_request_int_encode(1, 1, 1, MISSION), "MISSION_ITEM_INT")
        assert (second.seq, second.command, second.x) == (1, mav2.MAV_CMD_NAV_WAYPOINT, e7_of_float32(40.6340))
        transport.sendto(m.mission_ack_encode(1, 1, mav2.MAV_MISSION_ACCEPTED, MISSION).pack(m))
        # Rally points, now in int messages (the vehicle stays in the mode last used).
        request = await gcs.ask(m.mission_count_encode(1, 1, 1, RALLY), "MISSION_REQUEST_INT")
        rally = m.mission_item_int_encode(1, 1, 0, mav2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                          mav2.MAV_CMD_NAV_RALLY_POINT, 0, 0, 0, 0, 0, 0, 406330000, -86610000, 20, RALLY)
        assert (await gcs.ask(rally, "MISSION_ACK")).type == mav2.MAV_MISSION_ACCEPTED
        assert len(px4.missions.plans[RALLY]) == 1 and len(px4.missions.plans[MISSION]) == 2
        # What PX4 refuses is refused with a MISSION_ACK, never left unanswered.
        await gcs.ask(m.mission_count_encode(1, 1, 1, MISSION), "MISSION_REQUEST_INT")
        terminate = m.mission_item_int_encode(1, 1, 0, mav2.MAV_FRAME_MISSION, mav2.MAV_CMD_DO_FLIGHTTERMINATION,
                                              0, 1, 1, 0, 0, 0, 0, 0, 0, MISSION)
        assert (await gcs.ask(terminate, "MISSION_ACK")).type == mav2.MAV_MISSION_UNSUPPORTED
        await gcs.ask(m.mission_count_encode(1, 1, 1, MISSION), "MISSION_REQUEST_INT")
        vertex = m.mission_item_int_encode(1, 1, 0, mav2.MAV_FRAME_GLOBAL, mav2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                                           0, 0, 3, 0, 0, 0, 406330000, -86610000, 0, MISSION)
        assert (await gcs.ask(vertex, "MISSION_ACK")).type == mav2.MAV_MISSION_ERROR  # a fence item in a mission
        ack = await gcs.ask(m.mission_count_encode(1, 1, 65, mav2.MAV_MISSION_TYPE_FENCE), "MISSION_ACK")
        assert ack.type == mav2.MAV_MISSION_NO_SPACE
        assert len(px4.missions.plans[MISSION]) == 2  # refused uploads leave the stored plan alone
        # MISSION_CLEAR_ALL for every type.
        ack = await gcs.ask(m.mission_clear_all_encode(1, 1, mav2.MAV_MISSION_TYPE_ALL), "MISSION_ACK")
        assert ack.type == mav2.MAV_MISSION_ACCEPTED
        assert all(not items for items in px4.missions.plans.values())
    finally:
        transport.close()


@pytest.mark.parametrize("px4", ["px4", "ardupilot"], indirect=True)
async def test_a_health_flag_and_a_failsafe_reach_the_adapter_alike_on_both_autopilots(
    px4: MavlinkVehicle, mavsdk_fc: MavsdkFlightController,
) -> None:
    """What the ground judges a flicker or a failsafe from (issue 58 part 3: the same
    rule on both autopilots) reaches the agent's state the same way: a failing check
    shows and clears, a low battery's automatic return shows as `return_to_launch`."""
    async def state_is(what: str, check: Callable[[Any], bool]) -> None:
        async def ok() -> bool:
            return check(mavsdk_fc.state())
        await until(ok, 15, what)

    await state_is("every check passing", lambda s: s.health_failures == () and s.position is not None)
    px4.vehicle.inject_health_failure("global_position")
    await state_is("global_position failing", lambda s: "global_position" in s.health_failures)
    px4.vehicle.inject_health_failure()
    await state_is("the check passing again", lambda s: s.health_failures == ())
    await mavsdk_fc.arm()
    await mavsdk_fc.takeoff(5.0)
    await state_is("in the air", lambda s: s.landed_state == "in_air" and s.flight_mode == "hold")
    px4.vehicle.inject_battery(0.05)
    await state_is("the automatic return", lambda s: s.flight_mode == "return_to_launch")
