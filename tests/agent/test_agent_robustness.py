"""Bad input, a restarted router and bad configuration: the agent stays up, or
refuses to start with a clear message."""

from __future__ import annotations

import asyncio
import subprocess
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.bundles import BundleReply
from dronefleet.schemas.commands import CommandReply
from dronefleet.schemas.keys import Keys
from tests.harness import AgentProcess, Operator, fleet_command, open_ground_router
from tests.ports import free_port

pytestmark = pytest.mark.integration
OUTAGE_S = 1.0


@pytest.mark.parametrize(
    ("payload", "field"),
    [
        (b'{"cmd": "goto", "lat": "north", "lon": 8.5}', "lat"),
        (b'{"cmd": "goto", "lon": 8.5}', "lat"),
        (b'{"cmd": "fly_to_the_moon"}', "cmd"),
        (b'{"cmd": "takeoff", "alt": NaN}', "alt"),
        (b'{"cmd": "goto", "lat": 91.5, "lon": 8.5}', "lat"),
        (b'{"cmd": "goto", "lat": 40.1, "lon": -181}', "lon"),
        (b'{"cmd": "turn"}', "deg"),
        (b'{"cmd": "arm", "mode": "offboard"}', "mode"),
        (b'{"lat": 1}', "cmd"),
    ],
)
def test_bad_commands_name_the_field(payload: bytes, field: str) -> None:
    """Pure decoding: every refusal names the field at fault."""
    from dronefleet.schemas.commands import decode_command
    from dronefleet.schemas.errors import InvalidMessage

    with pytest.raises(InvalidMessage) as info:
        decode_command(payload)
    assert info.value.field == f"$.{field}"
    assert str(info.value).startswith(f"{field}:")


async def test_agent_refuses_bad_commands_and_keeps_running(
    agents: Callable[..., AgentProcess], operator: Callable[[str], Operator], client: ZenohBus
) -> None:
    agent = agents("drone02")
    op = operator("drone02")
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    cases = [
        (b'{"command_id": "c1", "cmd": "goto", "lat": "north", "lon": 8.5}', "lat"),
        (b'{"command_id": "c2", "cmd": "goto", "lon": 8.5}', "lat"),
        (b'{"command_id": "c3", "cmd": "fly_to_the_moon"}', "cmd"),
        (b'{"command_id": "c4", "cmd": "takeoff", "alt": NaN}', "alt"),
        (b'{"command_id": "c5", "cmd": "goto", "lat": 91.5, "lon": 8.5}', "lat"),
        (b'{"command_id": "c6", "cmd": "arm", "drone_id": "drone99"}', "drone_id"),
        (b"\x00\xff not json", None),
    ]
    for payload, field in cases:
        raw = await client.query(Keys().cmd("drone02"), payload, timeout_s=3)
        reply = msgspec.json.decode(raw, type=CommandReply)
        assert not reply.accepted, payload
        if field:
            assert (reply.reason or "").startswith(f"{field}:"), reply.reason
            assert reply.command_id == payload.split(b'"')[3].decode()
        else:
            assert "malformed" in (reply.reason or "")
    # The bundle queryable too: raw bytes, JSON that is not a bundle.
    for payload, words in ((b"\x00\xff not json", "malformed"), (b'{"steps": "all of them"}', "steps")):
        raw = await client.query(Keys().bundle("drone02"), payload, timeout_s=3)
        bundle_reply = msgspec.json.decode(raw, type=BundleReply)
        assert not bundle_reply.accepted and words in (bundle_reply.reason or ""), (payload, bundle_reply)
    # Still alive and commandable.
    assert agent.proc.poll() is None
    await op.expect(await op.accepted("arm"), "success", 10)
    await op.next_telemetry(lambda t: t.armed, 5, "armed telemetry")


async def test_agent_reconnects_after_the_router_restarts(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = await open_ground_router(endpoint)
    agent = AgentProcess("drone03", endpoint, tmp_path)
    client = await ZenohBus.open("client", connect=[endpoint])
    try:
        op = Operator(client, "drone03")
        await op.next_telemetry(timeout_s=30, what="telemetry before the restart")
        before = op.last.seq
        await router.close()
        # The outage itself (not a settling wait): a second with no router, during
        # which the agent's ten telemetry samples have nowhere to go.
        await asyncio.sleep(OUTAGE_S)
        router = await open_ground_router(endpoint)
        first = await op.next_telemetry(timeout_s=30, what="telemetry after the router restart")
        # Samples published while no router ran were lost, not buffered: a gap proves
        # the link really went down and came back.
        assert first.seq > before + 5
        t = await op.next_telemetry(lambda t: t.seq > first.seq + 5, 10, "steady telemetry again")
        assert t.drone_id == "drone03"
        assert agent.proc.poll() is None
    finally:
        agent.stop()
        await client.close()
        await router.close()


def run_agent_cli(tmp_path: Path, config: str) -> subprocess.CompletedProcess[str]:
    path = tmp_path / "agent.yml"
    path.write_text(config)
    return subprocess.run(
        fleet_command("agent", "--id", "drone01", "--config", str(path), "--fc", "sim"),
        capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL,
    )


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ("telemetry_rate_ms: 100\ntelemetry_rte_ms: 5\n", "unknown key 'telemetry_rte_ms'"),
        ("max_speed: fast\n", "max_speed"),
        ("acceptance_radius: -1\n", "acceptance_radius"),
        ("- not\n- a mapping\n", "expected a mapping"),
        ("key: [unclosed\n", "not valid YAML"),
    ],
)
def test_bad_agent_config_exits_with_code_2(tmp_path: Path, config: str, message: str) -> None:
    result = run_agent_cli(tmp_path, config)
    assert result.returncode == 2, result
    assert message in result.stderr
    assert str(tmp_path / "agent.yml") in result.stderr


def test_bad_drone_id_exits_with_code_2() -> None:
    result = subprocess.run(fleet_command("agent", "--id", "drone/*", "--fc", "sim"), capture_output=True, text=True, timeout=30)
    assert result.returncode == 2
    assert "drone/*" in result.stderr
