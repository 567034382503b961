"""The agent contract (SPEC §2–§3) over real Zenoh: a router in this process,
`fleet agent` as a subprocess, commands as real queries.

`flight_controller` (tests/agent/conftest.py) is parametrized per adapter; every test here
runs unchanged against each of them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from bench.autopilot_contract import fly_contract
from dronefleet.schemas.geo import destination, distance_m
from tests.harness import AgentProcess, Operator, at
from tests.waiting import until

pytestmark = pytest.mark.integration


@pytest.mark.slow(185)  # PX4's personality at its defaults: its start and landing times (autopilot_params.TIMING)
@pytest.mark.parametrize("flight_controller", ["mavsdk", "mavsdk-ardupilot"], indirect=True)
async def test_flight_contract(flight_controller: str, tmp_path: Path) -> None:
    """The whole contract as bench/autopilot_contract.py flies it against a real autopilot
    (SPEC §2–§3, §8), through `fleet agent` over real Zenoh, real MAVSDK and UDP, on
    `fleet sim` as PX4 (its default parameters) and as ArduCopter: telemetry, refusals,
    arm, takeoff, gotos, turn, move, cancel, a goto refused while landing, the
    auto-disarm announced, gotos queued in a takeoff, the return to the last arming's
    home and the lost-link failsafe. The built-in vehicle (`--fc sim`) is the same
    vehicle without MAVLink; the tests below and every mission test fly it."""
    result = await fly_contract(flight_controller, tmp_path)
    assert result.failed is None, f"{result.failed}: {result.why} (passed: {', '.join(result.passed)})"


SPAWN = (40.633490, -8.660815)  # where `--fc sim` and `fleet sim` put drone01


def _square(half_m: float) -> list[list[float]]:
    n, s = destination(*SPAWN, half_m, 0)[0], destination(*SPAWN, half_m, 180)[0]
    e, w = destination(*SPAWN, half_m, 90)[1], destination(*SPAWN, half_m, 270)[1]
    return [[n, w], [n, e], [s, e], [s, w]]


@pytest.mark.slow(55)
async def test_the_agent_keeps_its_geofence_whatever_path_a_command_takes(
    agents: Callable[..., AgentProcess], operator: Callable[[str], Operator], flight_controller: str, tmp_path: Path,
) -> None:
    """SPEC §11 at the agent, with no ground in the way: this operator queries
    drone/drone01/cmd directly. Flights out of the fence or over its ceiling are
    refused (reason `geofence`), return always goes through, the fence is uploaded to
    the flight controller, and a drone pushed outside (an offboard velocity, which
    names no target to check) is turned home by the agent's failsafe."""
    agents("drone01", fc=flight_controller, return_altitude=10, geofence={"polygon": _square(30), "max_alt_m": 20})
    op = operator("drone01")
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    log = tmp_path / "drone01.log"
    await until(lambda: "geofence of 4 vertices uploaded" in log.read_text(), 30, "the fence uploaded to the autopilot")

    high = await op.send("takeoff", alt=25)  # over max_alt_m 20 above home
    assert not high.accepted and high.reason is not None and high.reason.startswith("geofence: "), high
    await op.expect(await op.accepted("arm"), "success", 30)
    takeoff = await op.accepted("takeoff", alt=5)
    await op.expect(takeoff, "finish", 30)
    here = at(await op.next_telemetry())
    far = destination(here.lat, here.lon, 45, 0)
    out = await op.send("goto", lat=far[0], lon=far[1])
    assert not out.accepted and out.reason is not None and "outside the fence" in out.reason, out
    ahead = await op.send("move", y=40)  # forward (north), 40 m: past the edge at 30 m
    assert not ahead.accepted and ahead.reason is not None and ahead.reason.startswith("geofence: "), ahead
    inside = destination(here.lat, here.lon, 20, 0)
    await op.expect(await op.accepted("goto", lat=inside[0], lon=inside[1]), "finish", 30)

    await op.accepted("velocity_ned", north=4.0, east=0.0, down=0.0)  # out through the north edge
    failsafe = await op.system("failsafe", 30)
    assert failsafe.reason is not None and failsafe.reason.startswith("return: outside the geofence"), failsafe
    landed = await op.next_telemetry(lambda t: t.landed_state == "on_ground" and not t.armed, 90, "home, landed")
    assert distance_m(at(landed).lat, at(landed).lon, *SPAWN) < 2.0
