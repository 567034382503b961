"""Live traffic is readable with a stock third-party Zenoh tool, not only `fleet sub`.

`zenoh-cli` (PyPI, RISE-Maritime) subscribes to a running `fleet ground` as any client
would and must print the drones' telemetry and statuses as JSON (SPEC §2: every payload
is JSON so that `z_sub`/`zenoh-cli` show it). Real processes: a ground, one sim agent,
the `zenoh` command.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from tests.harness import GroundFleet

pytestmark = pytest.mark.integration

ZENOH_CLI = Path(sys.executable).with_name("zenoh")


@contextlib.asynccontextmanager
async def zenoh_subscribe(endpoint: str, *keys: str) -> AsyncIterator[asyncio.subprocess.Process]:
    """`zenoh subscribe` as a Zenoh client of the ground, one `KEY VALUE` line per sample."""
    args = [str(ZENOH_CLI), "--mode", "client", "--connect", endpoint, "--cfg", "scouting/multicast/enabled:false",
            "subscribe", "--decoder", "json", "--line", "{key} {value}"]
    for key in keys:
        args += ["-k", key]
    proc = await asyncio.create_subprocess_exec(*args, stdin=asyncio.subprocess.DEVNULL,
                                                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    try:
        yield proc
    finally:
        if proc.returncode is None:
            proc.kill()
        await proc.wait()


async def next_message(proc: asyncio.subprocess.Process, key_suffix: str, predicate: Any = lambda m: True,
                       timeout_s: float = 20) -> dict[str, Any]:
    """The first printed message on a key ending in `key_suffix` that satisfies `predicate`."""
    assert proc.stdout is not None

    async def scan() -> dict[str, Any]:
        while True:
            line = (await proc.stdout.readline()).decode()  # type: ignore[union-attr]
            if not line:
                stderr = (await proc.stderr.read()).decode() if proc.stderr else ""
                raise AssertionError(f"zenoh-cli exited ({proc.returncode}):\n{stderr}")
            key, _, value = line.rstrip("\n").partition(" ")
            message = json.loads(value)  # readable JSON, or the test fails here
            if key.endswith(key_suffix) and predicate(message):
                return message

    return await asyncio.wait_for(scan(), timeout_s)


async def test_zenoh_cli_shows_json_telemetry_and_statuses_of_a_running_ground(tmp_path: Path) -> None:
    fleet = GroundFleet(tmp_path, {"drone01": "sim://?lat=40.6334&lon=-8.660815&alt=8.2"})
    try:
        async with fleet.client() as http:
            async with zenoh_subscribe(fleet.ground.endpoint, "drone/*/telem", "drone/*/status") as sub:
                telem = await next_message(sub, "drone01/telem")
                assert telem["drone_id"] == "drone01"
                assert abs(telem["position"]["lat"] - 40.6334) < 1e-3 and telem["armed"] is False

                reply = await http.post("/drone/drone01/cmd", json={"cmd": "arm"})
                assert reply.status_code == 200, reply.text
                command_id = reply.json()["command_id"]
                status = await next_message(sub, "drone01/status", lambda m: m.get("command_id") == command_id
                                            and m.get("state") == "success")
                assert status["drone_id"] == "drone01" and status["command"] == "arm"
                armed = await next_message(sub, "drone01/telem", lambda m: m["armed"])
                assert armed["drone_id"] == "drone01"
    finally:
        fleet.stop()
