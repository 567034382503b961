"""Two grounds on one mesh (SPEC §14) with real processes: `fleet ground` twice, the
second joining the first's router, and an agent connected to both. The higher priority
is active, the other standby (everything visible, commands 503 naming the active one);
when the active ground dies the standby takes over with a newer epoch, the agent refuses
the old epoch (`stale_ground`), and the first ground, back, takes over again above it."""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.commands import CommandReply
from dronefleet.schemas.keys import Keys
from tests.harness import (
    AgentProcess,
    GroundProcess,
    ended,
    event_log,
    ground_active,
    grounds,
    submit,
    two_grounds,
    wait_state,
)
from tests.waiting import until

pytestmark = pytest.mark.integration


@pytest.mark.slow(30)
async def test_a_standby_ground_refuses_commands_then_takes_over_with_a_newer_epoch_when_the_active_one_dies(
        tmp_path: Path) -> None:
    alpha, bravo, agent = two_grounds(tmp_path)
    try:
        await alpha.ready()
        await bravo.ready()
        async with httpx.AsyncClient(base_url=alpha.url, timeout=10) as a, \
                httpx.AsyncClient(base_url=bravo.url, timeout=10) as b:
            await wait_state(a, "drone01", "ready", 30)
            await wait_state(b, "drone01", "ready", 30)  # the standby sees the fleet too

            async def bravo_standby() -> bool:
                g = await grounds(b)
                return (g.get("alpha", {}).get("active") is True and g.get("bravo", {}).get("active") is False
                        and g["alpha"].get("http") == alpha.url + "/")
            await until(bravo_standby, 20, "bravo standby, alpha active")
            assert (await grounds(a))["alpha"]["epoch"] == 1

            refused = await b.post("/drone/drone01/cmd", json={"cmd": "arm"})
            assert refused.status_code == 503, refused.text
            assert refused.json() == {"error": "standby", "active": "alpha", "http": alpha.url + "/"}
            assert (await b.post("/mission", content=b"print('hi')\n")).status_code == 503
            assert (await a.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
            mission_id = await submit(a, "print('hello from alpha')\n", "short")
            assert (await ended(a, mission_id, 30))["status"] == "finished"

            async def mission_copied() -> bool:  # its record and log follow too
                reply = await b.get(f"/ground/alpha/mission/{mission_id}")
                return (reply.status_code == 200 and reply.json()["status"] == "finished"
                        and "hello from alpha" in [x["message"] for x in reply.json()["log"]])
            await until(mission_copied, 10, "alpha's mission in bravo's copy")

            async def copied_live() -> bool:  # the standby keeps the active ground's log as it is written
                reply = await b.get("/ground/alpha/log")
                return reply.status_code == 200 and "drone01 - Success on arm" in reply.text
            await until(copied_live, 10, "alpha's log line of the arm in bravo's copy")

            killed_ms = time.time() * 1000
            alpha.kill()  # SIGKILL: no goodbye, its token goes with its links
            # Every line alpha had logged a second before it died is in bravo's copy.
            with sqlite3.connect(alpha.data_dir / "events.db") as db:
                logged = [f"{level.upper()} {drone or '-'} {message}" for level, drone, message in db.execute(
                    "SELECT level, drone_id, message FROM events WHERE timestamp_ms <= ? ORDER BY id", (killed_ms - 1000,))]
            copy = (await b.get("/ground/alpha/log")).text
            assert all(line.split(" ", 2)[2] in copy for line in logged), (logged, copy)
            assert "Ground alpha is active (epoch 1)" in copy and "Registered" in copy

            async def bravo_active() -> bool:
                return (await grounds(b)).get("bravo", {}).get("active") is True
            await until(bravo_active, 30, "bravo active after alpha died")
            assert (await grounds(b))["bravo"]["epoch"] == 2
            assert any("Ground bravo is active (epoch 2)" in line for line in await event_log(b))
            reply = await b.post("/drone/drone01/cmd", json={"cmd": "disarm"})
            assert reply.status_code == 200, reply.text

            # A command of the dead ground's epoch (a late one, or a partitioned ground) is fenced.
            stale = {"cmd": "arm", "drone_id": "drone01", "command_id": "late-1", "ground_epoch": 1}
            client = await ZenohBus.open("client", connect=[bravo.endpoint])
            try:
                answer = CommandReply(**json.loads(await client.query("drone/drone01/cmd", json.dumps(stale).encode())))
            finally:
                await client.close()
            assert (answer.accepted, answer.reason) == (False, "stale_ground"), answer
            assert "stale_ground" in agent.output()

            alpha.start()  # the same ports and data: its priority makes it the active one again
            await alpha.ready()
            await wait_state(a, "drone01", "ready", 30)

            async def alpha_back() -> bool:
                g = await grounds(b)
                return g.get("alpha", {}).get("active") is True and g.get("bravo", {}).get("active") is False
            await until(alpha_back, 30, "alpha active again, bravo standby")
            assert (await b.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 503
            assert (await a.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
            # Above bravo's: learnt from bravo, or (back alone, its data said 1, so it took 2
            # as bravo had) from the agent, which refuses an epoch another ground holds.
            assert (await grounds(a))["alpha"]["epoch"] == 3
            assert any("Ground bravo is standby" in line for line in await event_log(b))
    finally:
        agent.stop()
        bravo.stop()
        alpha.stop()


@pytest.mark.slow(15)
async def test_a_ground_that_lost_its_epoch_learns_the_agents_and_commands_above_it(tmp_path: Path) -> None:
    """A laptop replaced, or its data directory lost: the ground starts at epoch 1 while
    the drones hold a newer one. The first refusal (`stale_ground`, with the agent's
    epoch) teaches it; it takes one above and the command goes through."""
    ground = GroundProcess(tmp_path)
    agent = AgentProcess("drone01", ground.endpoint, tmp_path)
    try:
        for epoch in (1, 2, 3):  # each start one above the last (kept in the data directory)
            if epoch > 1:
                ground.start()
            await ground.ready()
            async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
                await wait_state(http, "drone01", "ready", 30)
                assert [g["epoch"] for g in (await http.get("/ground")).json()] == [epoch]
                for cmd in ("arm", "disarm"):  # the agent holds this epoch now
                    reply = await http.post("/drone/drone01/cmd", json={"cmd": cmd})
                    assert reply.status_code == 200, reply.text
            ground.stop()
        (ground.data_dir / "ground-epoch").unlink()
        ground.start()
        await ground.ready()
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            await wait_state(http, "drone01", "ready", 30)
            assert [g["epoch"] for g in (await http.get("/ground")).json()] == [1]
            reply = await http.post("/drone/drone01/cmd", json={"cmd": "arm"})
            assert reply.status_code == 200, reply.text
            assert [g["epoch"] for g in (await http.get("/ground")).json()] == [4]
            assert any("epoch 3 was in use" in line for line in (await http.get("/drone/logs")).text.splitlines())
    finally:
        agent.stop()
        ground.stop()


@pytest.mark.slow(15)
async def test_an_observer_sees_the_fleet_and_never_commands_even_ranked_highest_and_alone(tmp_path: Path) -> None:
    """`fleet ground --observer` (a command post): it sees the drones and the grounds,
    every command, push and mission is refused 403 naming the active ground, and it is
    never active — not with the highest priority, not once the only other ground died."""
    for d in ("alpha", "post"):
        (tmp_path / d).mkdir()
    alpha = GroundProcess(tmp_path / "alpha", ground_id="alpha")
    post = GroundProcess(tmp_path / "post", extra_args=["--observer"], ground_id="post", priority=100, connect=[alpha.endpoint])
    agent = AgentProcess("drone01", alpha.endpoint, tmp_path)
    try:
        await alpha.ready()
        await post.ready()
        async with httpx.AsyncClient(base_url=post.url, timeout=10) as p:
            await wait_state(p, "drone01", "ready", 30)

            async def alpha_active() -> bool:
                return (await grounds(p)).get("alpha", {}).get("active") is True
            await until(alpha_active, 20, "the observer hearing alpha active")
            me = (await grounds(p))["post"]
            assert (me["role"], me["active"], me["this"]) == ("observer", False, True), me
            for method, path, body in (("POST", "/drone/drone01/cmd", {"cmd": "arm"}),
                                       ("POST", "/drone/drone01/bundle", {"steps": [{"cmd": "arm"}]})):
                refused = await p.request(method, path, json=body)
                assert refused.status_code == 403, refused.text
                assert refused.json() == {"error": "observer", "active": "alpha", "http": alpha.url + "/"}
            assert (await p.post("/mission", content=b"print('hi')\n")).status_code == 403

            alpha.kill()

            async def alpha_gone() -> bool:
                return "alpha" not in await grounds(p)
            await until(alpha_gone, 30, "the observer noticing alpha gone")
            assert (await grounds(p))["post"]["active"] is False
            refused = await p.post("/drone/drone01/cmd", json={"cmd": "arm"})
            assert refused.status_code == 403 and refused.json()["active"] == "", refused.text
    finally:
        agent.stop()
        post.stop()
        alpha.stop()


@pytest.mark.slow(15)
async def test_a_ground_token_nothing_answers_for_does_not_make_the_active_ground_stand_down(tmp_path: Path) -> None:
    """A token `ground/alpha` with no ground behind it (what Zenoh's routers may keep
    after the ground was lost: ADR 0016) would win the rule by its id. Bravo, alone and
    active, asks it what it is until the mesh has had time to route, then leaves it
    uncounted and stays active; its commands still go out."""
    (tmp_path / "bravo").mkdir()
    bravo = GroundProcess(tmp_path / "bravo", ground_id="bravo")
    agent = AgentProcess("drone01", bravo.endpoint, tmp_path)
    ghost: ZenohBus | None = None
    try:
        await bravo.ready()
        async with httpx.AsyncClient(base_url=bravo.url, timeout=10) as b:
            await wait_state(b, "drone01", "ready", 30)
            await until(lambda: ground_active(b, "bravo"), 20, "bravo active")
            ghost = await ZenohBus.open("client", connect=[bravo.endpoint], wait=True)
            ghost.announce(Keys().ground("alpha"))
            await until(lambda: "alpha: its token is on the mesh but nothing answers" in bravo.output(), 30,
                        "bravo giving up on asking what alpha is")
            assert await ground_active(b, "bravo"), await grounds(b)
            assert (await b.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
    finally:
        if ghost is not None:
            await ghost.close()
        agent.stop()
        bravo.stop()
