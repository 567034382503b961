"""The MAVLink simulator and the MAVSDK adapter together: several vehicles, faults,
an independent MAVLink client, and start-up/shutdown behaviour of the agent."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink import mavutil

from bus.zenoh_bus import ZenohBus
from schemas.geo import destination, distance_m
from sim.faults import send_fault
from tests.harness import AgentProcess, Operator, SimProcess, fleet_command
from tests.helpers import free_udp_base

pytestmark = pytest.mark.integration


async def airborne(op: Operator, alt: float = 5) -> None:
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    await op.expect(await op.accepted("arm"), "success", 10)
    await op.expect(await op.accepted("takeoff", alt=alt), "finish", 30)


@pytest.mark.slow(21)
async def test_three_vehicles_from_fleet_sim_agents_fly_concurrently(endpoint: str, client: ZenohBus, tmp_path: Path) -> None:
    config = tmp_path / "agent.yml"
    config.write_text("telemetry_rate_ms: 200\n")
    sim = SimProcess(tmp_path, n=3, extra_args=["--agents", "--connect", endpoint, "--agent-config", str(config)])
    try:
        ops = [Operator(client, f"drone0{i}") for i in (1, 2, 3)]

        async def fly(op: Operator, metres: float) -> tuple[float, float]:
            await airborne(op, alt=3 + metres / 10)
            here = op.last.position
            lat, lon = destination(here.lat, here.lon, metres, 0)
            await op.expect(await op.accepted("goto", lat=lat, lon=lon, yaw=None), "finish", 40)
            await op.expect(await op.accepted("land"), "finish", 40)
            return lat, lon

        started = time.monotonic()
        targets = await asyncio.gather(*(fly(op, m) for op, m in zip(ops, (20, 25, 30), strict=True)))
        elapsed = time.monotonic() - started
        for op, (lat, lon) in zip(ops, targets, strict=True):
            t = await op.next_telemetry()
            assert t.landed_state == "on_ground"
            assert distance_m(t.position.lat, t.position.lon, lat, lon) < 1.0
        # Concurrent, not one after the other: one flight alone takes ~15-20 s.
        assert elapsed < 60, elapsed
        homes = {round(op.last.home.lon, 6) for op in ops}
        assert len(homes) == 3  # three distinct vehicles, not one System seen thrice
    finally:
        sim.stop()
    assert sim.proc.returncode == 0
    assert "agent drone03 started" in sim.log.read_text()


@pytest.fixture
def sim_and_agent(agents: Callable[..., AgentProcess], tmp_path: Path) -> tuple[SimProcess, AgentProcess]:
    sim = SimProcess(tmp_path)
    agent = agents("drone01", fc=sim.fc_url())
    yield sim, agent
    sim.stop(signal.SIGKILL)


async def test_simulator_killed_mid_flight_disconnects_then_reconnects(sim_and_agent, operator) -> None:
    sim, _ = sim_and_agent
    op = operator("drone01")
    await airborne(op)
    await op.system("connect", 5)
    sim.stop(signal.SIGKILL)
    killed = time.monotonic()
    await op.system("disconnect", 5)
    assert time.monotonic() - killed < 5
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
    here = op.last.position
    lat, lon = destination(here.lat, here.lon, 200, 0)
    goto = await op.accepted("goto", lat=lat, lon=lon)
    await op.expect(goto, "start", 10)
    assert (await send_fault("drone01", "rc_takeover", None, sim.control))["ok"]
    await op.system("start_manual", 5)
    cancelled = await op.expect(goto, "cancel", 5)
    assert cancelled.reason == "manual control"
    assert (await send_fault("drone01", "rc_release", None, sim.control))["ok"]
    await op.system("stop_manual", 5)


@pytest.mark.slow(20)
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
    from agent.fc_mavsdk import mavsdk_url

    assert mavsdk_url(url) == expected


@pytest.mark.parametrize("url", ["serial:///dev/ttyACM0:fast", "ftp://x", "udp://"])
def test_bad_flight_controller_urls(url: str) -> None:
    from agent.fc_mavsdk import mavsdk_url
    from schemas.errors import ConfigError

    with pytest.raises(ConfigError):
        mavsdk_url(url)
