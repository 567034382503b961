"""The ground through failures: an agent killed and restarted, the ground itself killed
and restarted on the same data directory, and a clean stop with a live event stream."""

from __future__ import annotations

import asyncio
import signal
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from tests.harness import AgentProcess, GroundProcess, drone_state, fleet_command, wait_state
from tests.waiting import until

pytestmark = pytest.mark.integration


@pytest.fixture
async def ground_and_agent(tmp_path: Path) -> AsyncIterator[tuple[GroundProcess, AgentProcess]]:
    """A ground and one sim agent, drone01 registered and ready."""
    ground = GroundProcess(tmp_path)
    agent = AgentProcess("drone01", ground.endpoint, tmp_path)
    try:
        await ground.ready()
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            await wait_state(http, "drone01", "ready", 30)
        yield ground, agent
    finally:
        agent.stop()
        ground.stop()


async def test_killed_agent_is_unknown_and_ready_again_after_restart(ground_and_agent: tuple[GroundProcess, AgentProcess]) -> None:
    ground, agent = ground_and_agent
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        agent.kill()
        # A killed agent's TCP link closes at once (how soon is bench/mesh.py's failover
        # figure); here a liveness deadline.
        await wait_state(http, "drone01", "unknown", 15.0)
        log = (await http.get("/drone/logs", params={"drone_id": "drone01", "loglevel": "warn"})).text
        assert "WARN drone01 - Link lost: stopped receiving messages from drone" in log
        refused = await http.post("/drone/drone01/cmd", json={"cmd": "arm"})
        assert refused.status_code == 409 and "unknown" in refused.json()["error"]
        # `return` always goes through the ground; nobody answers it: 504.
        unreachable = await http.post("/drone/drone01/cmd", json={"cmd": "return"})
        assert unreachable.status_code == 504, unreachable.text
        assert "drone01" in unreachable.json()["error"]

        agent.start()
        await wait_state(http, "drone01", "ready", 30)
        lines = (await http.get("/drone/logs", params={"drone_id": "drone01"})).text.splitlines()
        stopped = max(i for i, line in enumerate(lines) if "Link lost: stopped receiving messages" in line)
        assert any("Link restored: established connection with ground station" in line for line in lines[stopped:])


async def test_killed_ground_restarted_on_the_same_data_dir_keeps_every_log_line(ground_and_agent: tuple[GroundProcess, AgentProcess]) -> None:
    ground, _ = ground_and_agent
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        assert (await http.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
        await until(lambda: _has(http, "Success on arm"), 10, "the arm in the log")
        before = (await http.get("/drone/logs")).text
    ground.kill()  # SIGKILL: no chance to flush anything
    ground.start()
    await ground.ready()
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        after = (await http.get("/drone/logs")).text
        assert after.startswith(before), f"lines lost across the crash:\nbefore:\n{before}\nafter:\n{after}"
        assert "Success on arm" in before and after.count("Ground station started") == 2
        # The agent finds the new router by itself and registers again.
        await until(lambda: _registered(http), 30, "drone01 registered with the restarted ground")


async def _has(http: httpx.AsyncClient, text: str) -> bool:
    return text in (await http.get("/drone/logs")).text


async def _registered(http: httpx.AsyncClient) -> bool:
    return await drone_state(http, "drone01") not in (None, "unknown")


async def test_sigterm_stops_the_ground_cleanly_even_with_an_open_event_stream(tmp_path: Path) -> None:
    ground = GroundProcess(tmp_path)
    await ground.ready()
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        connected, ended = asyncio.Event(), asyncio.Event()

        async def listen() -> None:
            async with http.stream("GET", "/events", timeout=None) as response:
                connected.set()
                async for _ in response.aiter_lines():
                    pass
            ended.set()

        listener = asyncio.get_running_loop().create_task(listen())
        try:
            async with asyncio.timeout(10):
                await connected.wait()
            code = await asyncio.to_thread(ground.stop, signal.SIGTERM)  # fails if not stopped in 10 s
            async with asyncio.timeout(5):
                await ended.wait()  # the stream ended normally, not by a broken connection
        finally:
            listener.cancel()
            await asyncio.gather(listener, return_exceptions=True)
    assert code == 0, ground.output()
    assert "Traceback" not in ground.output()
    restarted = GroundProcess(tmp_path, data_dir=ground.data_dir)
    try:
        await restarted.ready()
        async with httpx.AsyncClient(base_url=restarted.url) as http:
            assert "INFO - Ground station stopped" in (await http.get("/drone/logs")).text
    finally:
        restarted.stop()


async def test_an_event_stream_that_registers_while_the_ground_stops_still_ends() -> None:
    """The race behind a flaky SIGTERM test: the server accepted /events, sent its
    headers, and the stream's watcher registered only after end_watches() — it waited
    for uvicorn's grace and was cut. Now it ends at once."""
    from dronefleet.compose import SimField
    from dronefleet.sim.world import DroneSpec, World

    sim = SimField(World(drones=[DroneSpec(id="drone01", lat=40.63, lon=-8.66)]))
    try:
        with sim.station.watch() as early:
            sim.station.end_watches()
            with sim.station.watch() as late:
                assert late.queue.get_nowait().kind == "end"
            assert early.queue.get_nowait().kind == "end"
    finally:
        await sim.close()


def test_bad_ground_config_is_a_clear_error_at_start(tmp_path: Path) -> None:
    import subprocess

    config = tmp_path / "ground.yml"
    config.write_text("battery:\n  lowe: 0.2\n")
    result = subprocess.run(fleet_command("ground", "--config", str(config)), capture_output=True, text=True, timeout=30)
    assert result.returncode == 2
    assert "unknown key 'battery.lowe'" in result.stderr and str(config) in result.stderr


def test_http_port_in_use_is_a_clear_error(tmp_path: Path) -> None:
    import socket
    import subprocess

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = subprocess.run(
            fleet_command("ground", "--http-port", str(port), "--data-dir", str(tmp_path / "d"), "--listen", "tcp/127.0.0.1:0"),
            capture_output=True, text=True, timeout=30,
        )
    assert result.returncode == 2, result.stderr
    assert f"cannot serve HTTP on 127.0.0.1:{port}" in result.stderr and "Traceback" not in result.stderr


def test_the_shipped_ground_config_loads() -> None:
    from dronefleet.ground.config import GroundConfig
    from dronefleet.schemas.config_loading import load_config
    from tests.harness import REPO

    config = load_config(GroundConfig, REPO / "deploy" / "ground.yml", {})
    assert config.http_host == "0.0.0.0" and config.sensor_timeout_ms == {"temperature": 10000}
