"""The ground station end to end: `fleet ground` and three `fleet agent --fc sim` as
subprocesses over real Zenoh through the ground's router, driven over real HTTP."""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import subprocess
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.codec import encode
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import SensorReading
from tests.harness import GroundFleet, fleet_command, signal_and_wait, wait_state
from tests.ports import free_udp_base
from tests.waiting import Collector, until

# One worker runs them all, on the module's one fleet: spread over the workers, each
# started a fleet of its own for its one or two tests. The group holds the other
# modules with a fleet of their own too, one after the other (ADR 0011).
pytestmark = [pytest.mark.integration, pytest.mark.xdist_group("module-fleets")]

DRONES = ("drone01", "drone02", "drone03")
SPAWNS = {"drone01": (40.633490, -8.660815), "drone02": (40.633590, -8.660815), "drone03": (40.633690, -8.660815)}


class Fleet(GroundFleet):
    def __init__(self, tmp: Path) -> None:
        self.control_port = free_udp_base(1)
        fcs = {d: f"sim://?lat={lat}&lon={lon}&alt=8.2" for d, (lat, lon) in SPAWNS.items()}
        fcs["drone03"] += f"&control={self.control_port}"
        super().__init__(tmp, fcs, sensor_timeout_ms={"temperature": 0})


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    fleet = Fleet(tmp_path_factory.mktemp("fleet"))
    yield fleet
    fleet.stop()


@pytest.fixture
async def http(fleet: Fleet) -> AsyncIterator[httpx.AsyncClient]:
    async with fleet.client(drones_ready=False) as client:
        yield client


async def states(http: httpx.AsyncClient) -> dict[str, str]:
    return {v["info"]["drone_id"]: v["info"]["state"] for v in (await http.get("/drone", params={"data": "info"})).json()}


async def all_ready(http: httpx.AsyncClient) -> None:
    await until(lambda: _all_ready(http), 30, "three ready drones")


async def _all_ready(http: httpx.AsyncClient) -> bool:
    return await states(http) == dict.fromkeys(DRONES, "ready")


async def all_known(http: httpx.AsyncClient) -> None:
    """The three drones registered and none unknown (earlier tests may leave one flying)."""
    async def known() -> bool:
        now = await states(http)
        return sorted(now) == list(DRONES) and "unknown" not in now.values()

    await until(known, 30, "three registered drones")


async def log_lines(http: httpx.AsyncClient, **params: Any) -> list[str]:
    text = (await http.get("/drone/logs", params=params)).text
    return [line.split(" - ", 1)[1] for line in text.splitlines() if " - " in line]


async def post(http: httpx.AsyncClient, drone_id: str, body: Any) -> httpx.Response:
    content = body if isinstance(body, bytes) else json.dumps(body).encode()
    return await http.post(f"/drone/{drone_id}/cmd", content=content, headers={"content-type": "application/json"})


class EventStream:
    """GET /events read in the background; events collected by kind."""

    def __init__(self, http: httpx.AsyncClient) -> None:
        self.events = Collector()
        self._task = asyncio.get_running_loop().create_task(self._read(http), name="sse reader")

    async def _read(self, http: httpx.AsyncClient) -> None:
        async with http.stream("GET", "/events", timeout=None) as response:
            assert response.headers["content-type"].startswith("text/event-stream")
            kind = None
            async for line in response.aiter_lines():
                if line.startswith("event:"):
                    kind = line.split(":", 1)[1].strip()
                elif line.startswith("data:") and kind:
                    self.events((kind, json.loads(line.split(":", 1)[1])))

    async def close(self) -> None:
        """Stop reading; a reader that failed (a wrong content type, a bad event) fails the test."""
        if self._task.done() and not self._task.cancelled() and (exc := self._task.exception()) is not None:
            raise AssertionError("the /events reader failed") from exc
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)


async def test_three_agents_register_ready_and_filters_work(fleet: Fleet, http: httpx.AsyncClient) -> None:
    await all_ready(http)
    everything = (await http.get("/drone")).json()
    assert sorted(v["info"]["drone_id"] for v in everything) == list(DRONES)
    assert all(set(v) == {"info", "telem", "sensors"} for v in everything)
    assert [set(v) for v in (await http.get("/drone", params={"data": "telem"})).json()] == [{"telem"}] * 3
    assert len((await http.get("/drone", params={"state": "ready"})).json()) == 3
    assert (await http.get("/drone", params={"state": "hold"})).json() == []
    one = (await http.get("/drone/drone02")).json()
    assert one["telem"]["drone_id"] == "drone02" and one["info"]["current_command"] is None

    # A sensor program on drone02's SBC publishes a temperature: the filter finds it.
    bus = await ZenohBus.open("client", connect=[fleet.ground.endpoint])
    try:
        reading = SensorReading(drone_id="drone02", timestamp=int(time.time() * 1000), type="temperature", value=21.5, unit="degC")
        bus.publish(Keys().sensor("drone02", "temperature"), encode(reading))

        async def found() -> list[Any]:
            return (await http.get("/drone", params={"sensors": "temperature"})).json()

        matches = await until(found, 10, "a drone with a temperature sensor")
    finally:
        await bus.close()
    assert [m["info"]["drone_id"] for m in matches] == ["drone02"]
    assert matches[0]["sensors"][0]["value"] == 21.5
    assert "Detected temperature sensor" in await log_lines(http, drone_id="drone02")
    assert (await http.get("/drone", params={"sensors": ["temperature", "camera"]})).json() == []


async def test_arm_takeoff_goto_fly_active_then_hold_with_thesis_log_lines(fleet: Fleet, http: httpx.AsyncClient) -> None:
    await all_ready(http)
    stream = EventStream(http)
    try:
        assert (await post(http, "drone01", {"cmd": "arm"})).status_code == 200
        reply = await post(http, "drone01", {"cmd": "takeoff", "alt": 10})
        assert reply.status_code == 200, reply.text
        assert reply.json()["accepted"] is True and reply.json()["command_id"]
        lat, lon = SPAWNS["drone01"]
        target = {"cmd": "goto", "lat": round(lat + 0.0001, 6), "lon": lon}
        assert (await post(http, "drone01", target)).status_code == 200  # queued behind the takeoff

        def after_goto() -> list[str]:
            """drone01's states from the moment its goto runs."""
            seen = [d for k, d in stream.events.items if k == "drone" and d["drone_id"] == "drone01"]
            start = next((i for i, d in enumerate(seen) if (d["current_command"] or {}).get("command") == "goto"), None)
            return [] if start is None else [d["state"] for d in seen[start:]]

        await until(lambda: after_goto()[-1:] == ["hold"], 60, "drone01 active (goto) then hold")
        assert after_goto()[0] == "active"
    finally:
        await stream.close()
    kinds = {k for k, _ in stream.events.items}
    assert {"telemetry", "status", "drone", "log"} <= kinds
    info = (await http.get("/drone/drone01", params={"data": "info"})).json()["info"]
    assert info["state"] == "hold" and info["current_command"] is None

    lines = await log_lines(http, drone_id="drone01")
    goto = f"go to {target['lat']:.6f}, {target['lon']:.6f} at"
    expected = [
        "Registered", "Established connection with ground station", "Success on arm",
        "Start takeoff with altitude 10.0m", f"Queued {goto}", "Finish takeoff", f"Start {goto}", f"Finish {goto}",
    ]
    positions = [next((i for i, line in enumerate(lines) if line.startswith(e)), -1) for e in expected]
    assert -1 not in positions and positions == sorted(positions), "log lines out of order:\n" + "\n".join(lines)
    assert all(" drone01 - " in line for line in (await http.get("/drone/logs", params={"drone_id": "drone01"})).text.splitlines())


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        (b'{"cmd": "takeoff", "alt": ', None, "malformed JSON"),
        ({"cmd": "fly"}, "cmd", "unknown command"),
        ({"cmd": "takeoff", "alt": "high"}, "alt", "Expected `float"),
        ({"cmd": "goto", "lat": 40.6}, "lon", "missing required field"),
        (b'{"cmd": "goto", "lat": NaN, "lon": 1}', "lat", "finite"),
        ([1, 2], None, "JSON object"),
        ({"cmd": "arm", "drone_id": "drone02"}, "drone_id", "drone01"),
    ],
)
async def test_malformed_commands_are_400_naming_the_field(
    fleet: Fleet, http: httpx.AsyncClient, body: Any, field: str | None, words: str
) -> None:
    await all_known(http)
    response = await post(http, "drone01", body)
    assert response.status_code == 400, response.text
    error = response.json()
    assert words in error["error"]
    if field is not None:
        assert error["detail"]["field"] == field


async def test_unknown_drone_404_agent_refusal_409_and_manual_mode_409_but_return_200(fleet: Fleet, http: httpx.AsyncClient) -> None:
    await all_known(http)
    assert (await post(http, "ghost", {"cmd": "arm"})).status_code == 404
    missing = await http.get("/drone/ghost")
    assert missing.status_code == 404 and "ghost" in missing.json()["error"]

    refused = await post(http, "drone02", {"cmd": "takeoff"})  # disarmed: the agent says no
    assert refused.status_code == 409 and refused.json()["error"] == "disarmed"

    manual = subprocess.run(
        fleet_command("fault", "drone03", "rc_takeover", "--control", f"127.0.0.1:{fleet.control_port}"),
        capture_output=True, text=True, timeout=30,
    )
    assert manual.returncode == 0, manual.stderr
    try:
        await wait_state(http, "drone03", "manual", 10)
        conflict = await post(http, "drone03", {"cmd": "arm"})
        assert conflict.status_code == 409 and "manual" in conflict.json()["error"]
        home = await post(http, "drone03", {"cmd": "return"})
        assert home.status_code == 200, home.text
        assert "Refused arm: drone is under manual control" in await log_lines(http, drone_id="drone03", loglevel="warn")
    finally:
        subprocess.run(fleet_command("fault", "drone03", "rc_release", "--control", f"127.0.0.1:{fleet.control_port}"), timeout=30)
    await wait_state(http, "drone03", "ready", 20)


async def test_cli_lists_shows_commands_and_reads_logs(fleet: Fleet, http: httpx.AsyncClient) -> None:
    # The list below names all three: each must have registered (an earlier test on this
    # worker's fleet may leave drone01 hovering: waiting for it to be `ready` never ended
    # when the two ran in that order); drone02, which this test arms, must be ready.
    await all_known(http)
    await wait_state(http, "drone02", "ready", 60)
    url = ["--url", fleet.ground.url]

    def fleet_cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(fleet_command(*args), capture_output=True, text=True, timeout=30)

    table = fleet_cli("drone", "list", *url)
    assert table.returncode == 0, table.stderr
    header, *rows = table.stdout.splitlines()
    assert header.split()[:3] == ["DRONE", "STATE", "BATTERY"]
    assert sorted(r.split()[0] for r in rows) == list(DRONES)
    shown = fleet_cli("drone", "show", "drone02", *url)
    assert json.loads(shown.stdout)["info"]["drone_id"] == "drone02"

    armed = fleet_cli("drone", "cmd", "drone02", "arm", *url)
    assert armed.returncode == 0 and "accepted arm" in armed.stdout
    disarmed = fleet_cli("drone", "cmd", "drone02", "disarm", *url)
    assert disarmed.returncode == 0, disarmed.stderr
    bad = fleet_cli("drone", "cmd", "drone02", "takeoff", "alt=high", *url)
    assert bad.returncode == 1 and "400" in bad.stderr and "alt" in bad.stderr
    ghost = fleet_cli("drone", "cmd", "ghost", "arm", *url)
    assert ghost.returncode == 1 and "404" in ghost.stderr

    logs = fleet_cli("logs", "--drone", "drone02", *url)
    assert "drone02 - Success on arm" in logs.stdout
    assert all(" drone02 - " in line for line in logs.stdout.splitlines())
    warns = fleet_cli("logs", "--level", "warn", "--level", "error", *url)
    assert all((" WARN " in line or " ERROR " in line) for line in warns.stdout.splitlines())

    follow = subprocess.Popen(fleet_command("logs", "--follow", "--drone", "drone02", *url), stdout=subprocess.PIPE, text=True)
    reader: asyncio.Future[None] | None = None
    try:
        assert (await post(http, "drone02", {"cmd": "arm"})).status_code == 200
        assert follow.stdout is not None
        seen: list[str] = []

        async def two_arms() -> None:
            while sum("Success on arm" in s for s in seen) < 2:
                line = await asyncio.to_thread(follow.stdout.readline)  # type: ignore[union-attr]
                assert line, f"`fleet logs --follow` ended: {seen}"
                seen.append(line)

        # A silent follower must not hold the test until pytest's timeout: after the
        # deadline the finally below stops it, which ends the pending readline.
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.shield(reader := asyncio.ensure_future(two_arms())), 15)
        assert sum("Success on arm" in s for s in seen) == 2, seen  # the old one, then the new
    finally:
        signal_and_wait(follow, signal.SIGINT, 10, "fleet logs --follow")
        if reader is not None:
            await asyncio.gather(reader, return_exceptions=True)  # its readline sees EOF now
    assert (await post(http, "drone02", {"cmd": "disarm"})).status_code == 200

    unreachable = subprocess.run(fleet_command("drone", "list", "--url", "http://127.0.0.1:9"), capture_output=True, text=True, timeout=30)
    assert unreachable.returncode == 1 and "cannot reach the ground" in unreachable.stderr
