"""Lost link as autopilots do it (SPEC §8, issue 30), on real Zenoh with `fleet agent`.

The lost-link timers are short here (1 s to notice, 3 s from hold to return), so a
failsafe that should not run would run many times over within each test:
- on a mesh with no ground (a plain router, a Zenoh client commanding the drone, as
  the README invites) the agent never runs it, through a whole flight;
- once it has heard a ground and loses it in the air, it holds, then returns;
- disarmed on the ground it reports `link_lost` and does nothing.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import msgspec
import pytest

from dronefleet.bus.port import Sample
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.geo import destination
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.status import CommandStatus, SystemStatus
from dronefleet.schemas.telemetry import GROUND_PEER, LinkQuality
from tests.harness import AgentProcess, Operator, open_ground_router
from tests.ports import free_port

pytestmark = pytest.mark.integration
LOST_LINK = {"timeout_s": 1, "action": "hold", "return_after_s": 3}


@pytest.fixture
async def bare_router() -> AsyncIterator[tuple[str, ZenohBus]]:
    """A plain Zenoh router: no `ground/alive`, no `ground/ping`."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = await ZenohBus.open("router", listen=[endpoint])
    try:
        yield endpoint, bus
    finally:
        await bus.close()


async def heard_the_ground(bus: ZenohBus) -> None:
    """Until the agent reports an answered probe to the ground (its LinkQuality)."""
    answered = asyncio.Event()

    def on_link(sample: Sample) -> None:
        report = msgspec.json.decode(sample.payload, type=LinkQuality)
        if report.peer == GROUND_PEER and report.rtt_ms is not None:
            answered.set()

    sub = bus.subscribe(Keys().link("drone01"), on_link)
    try:
        async with asyncio.timeout(30):
            await answered.wait()
    finally:
        sub.close()


def _failsafes(op: Operator) -> list[SystemStatus]:
    return [s for s in op.status.items if isinstance(s, SystemStatus) and s.state in ("link_lost", "failsafe")]


@pytest.mark.slow(60)
# The lost-link policy is the agent's, the same over every adapter: the built-in sim
# holds it here; the MAVSDK adapter (PX4 and ArduCopter) flies the lost-link failsafe in
# test_agent_contract.py's contract.
@pytest.mark.parametrize("flight_controller", ["sim"], indirect=True)
async def test_with_no_ground_on_the_mesh_a_directly_commanded_flight_never_runs_the_failsafe(
    bare_router: tuple[str, ZenohBus], flight_controller: str, tmp_path: Path
) -> None:
    endpoint, _ = bare_router
    client = await ZenohBus.open("client", connect=[endpoint])
    agent = AgentProcess("drone01", endpoint, tmp_path, fc=flight_controller, lost_link=LOST_LINK,
                         probe_period_ms=250, acceptance_radius=1.0, return_altitude=10)
    try:
        op = Operator(client, "drone01")
        first = await op.next_telemetry(timeout_s=60, what="first telemetry")
        home = first.position
        assert home is not None
        await op.expect(await op.accepted("arm"), "success", timeout_s=30)
        takeoff = await op.accepted("takeoff", alt=8)
        # Queued behind the takeoff: only the last of several survives (SPEC §2).
        await op.accepted("goto", lat=destination(home.lat, home.lon, 15, 0)[0], lon=home.lon)
        east = destination(home.lat, home.lon, 20, 90)
        goto = await op.accepted("goto", lat=east[0], lon=east[1])
        await op.expect(takeoff, "finish", timeout_s=60)
        await op.expect(goto, "finish", timeout_s=60)
        await op.expect(await op.accepted("turn", deg=90), "finish", timeout_s=30)
        await op.expect(await op.accepted("move", y=10, speed=4), "finish", timeout_s=30)
        await op.expect(await op.accepted("return"), "finish", timeout_s=90)
        await op.next_telemetry(lambda t: not t.armed, timeout_s=60, what="disarmed after the return")
        assert _failsafes(op) == [], _failsafes(op)
        assert "failsafe" not in agent.output()
        # Every command of the flight ended on its own: none was cancelled by the agent.
        cancelled = [s for s in op.status.items if isinstance(s, CommandStatus) and s.state == "cancel"
                     and "failsafe" in (s.reason or "")]
        assert cancelled == []
    finally:
        agent.stop()
        await client.close()


@asynccontextmanager
async def heard_agent(tmp_path: Path) -> AsyncIterator[tuple[ZenohBus, Operator]]:
    """A ground (a router answering probes), an agent that has heard it, and an
    operator reaching the agent through the agent's own router, which outlives the
    ground: yields the ground, to be closed by the test, and the operator."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ground = await open_ground_router(endpoint)
    own = free_port()
    agent = AgentProcess("drone01", endpoint, tmp_path, lost_link=LOST_LINK, probe_period_ms=250,
                         listen=[f"tcp/127.0.0.1:{own}"])
    client = await ZenohBus.open("client", connect=[f"tcp/127.0.0.1:{own}"], wait=True)
    try:
        op = Operator(client, "drone01")
        await op.next_telemetry(timeout_s=60, what="first telemetry")
        yield ground, op
    finally:
        agent.stop()
        await client.close()
        await ground.close()


@pytest.mark.slow(40)
async def test_after_hearing_a_ground_a_loss_in_the_air_holds_then_returns(tmp_path: Path) -> None:
    async with heard_agent(tmp_path) as (ground, op):
        await op.expect(await op.accepted("arm"), "success", timeout_s=30)
        await op.expect(await op.accepted("takeoff", alt=8), "finish", timeout_s=60)
        await heard_the_ground(op.bus)
        await ground.close()
        lost = await op.system("link_lost", timeout_s=15)
        hold = await op.system("failsafe", timeout_s=10)
        assert hold.reason == "hold"
        back = await op.status.wait_for(
            lambda s: isinstance(s, SystemStatus) and s.state == "failsafe" and s.reason == "return", 15, "return")
        # The return counts from the hold (3 s), on the agent's own timestamps.
        assert back.timestamp - hold.timestamp >= 3000 - 300, (hold, back)
        assert hold.timestamp >= lost.timestamp


@pytest.mark.slow(30)
async def test_disarmed_on_the_ground_a_lost_ground_is_reported_and_nothing_is_done(tmp_path: Path) -> None:
    async with heard_agent(tmp_path) as (ground, op):
        await heard_the_ground(op.bus)
        await ground.close()
        await op.system("link_lost", timeout_s=15)
        # Well past the hold and return timers (1 s + 3 s): 5 s more of 100 ms telemetry,
        # still disarmed on the ground, and no failsafe.
        until_seq = op.last.seq + 50
        await op.next_telemetry(lambda t: t.seq >= until_seq, timeout_s=30, what="5 s of telemetry")
        assert [s for s in op.status.items if isinstance(s, SystemStatus) and s.state == "failsafe"] == []
        assert not op.last.armed and op.last.landed_state == "on_ground"
