"""An agent process keeps OpenSSL out (agent/footprint.py) and still does what needed it:
digests of task bundles and constant-time comparisons fall back to Python's own."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.launch import command_of
from dronefleet.schemas.bundles import BundleReply
from dronefleet.schemas.keys import Keys
from tests.harness import AgentProcess, Operator


@pytest.mark.parametrize(("argv", "command"), [
    (["agent", "--id", "d1"], "agent"),
    (["-vv", "agent", "--id", "d1"], "agent"),
    (["ground", "--id", "agent"], "ground"),
    (["--help"], None),
])
def test_the_command_is_the_first_word_after_the_flags(argv: list[str], command: str | None) -> None:
    assert command_of(argv) == command


def _mapped(pid: int) -> set[str]:
    return {Path(line.split()[-1]).name for line in Path(f"/proc/{pid}/maps").read_text().splitlines()
            if "/" in line}


async def test_an_agent_process_maps_no_openssl_and_still_takes_bundles(
    agents: Callable[..., AgentProcess], operator: Callable[[str], Operator], client: ZenohBus
) -> None:
    agent = agents("drone04")
    op = operator("drone04")
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    openssl = {name for name in _mapped(agent.proc.pid) if name.startswith(("libcrypto", "libssl", "_ssl", "_hashlib"))}
    assert not openssl, f"the agent loaded {sorted(openssl)}"
    # Accepting a bundle digests its content (blake2b): Python's built-in one.
    bundle = {"bundle_id": "b-footprint", "steps": [{"cmd": "arm"}]}
    raw = await client.query(Keys().bundle("drone04"), msgspec.json.encode(bundle), timeout_s=5)
    reply = msgspec.json.decode(raw, type=BundleReply)
    assert reply.accepted, reply
    assert agent.proc.poll() is None
