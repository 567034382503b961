"""Durable missions (SPEC §14): a mission running on the active ground goes on on the
standby when the active ground is killed, replayed from its journal, then live — with
real processes: two `fleet ground`, three sim agents connected to both, real Zenoh,
real SQLite.

What the drones did is read on the mesh itself (every command status the agents
published), not from either ground: each verb's command is accepted and run once."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from dronefleet.bus.port import Sample
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.codec import decode_status
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.status import CommandStatus
from tests.harness import GroundProcess, ended, ground_active, stop_all, submit, two_grounds_and_fleet, wait_state
from tests.waiting import until

pytestmark = pytest.mark.integration

HOME = (40.633400, -8.660810)
SPAWNS = {"drone01": HOME, "drone02": destination(*HOME, 15, 90), "drone03": destination(*HOME, 30, 90)}
LEG_M = 8
LEGS = 4
SCRIPT = f'''d1, d2 = assign("drone01", "drone02")

def scout(d):
    arm(d)
    takeoff(d, 6*m)
    channel.up = True
    for leg in range({LEGS}):
        move(d, forward={LEG_M}*m)
    land(d)

def follow(d):
    go = channel.up
    arm(d)
    takeoff(d, 9*m)
    for leg in range({LEGS}):
        move(d, forward={LEG_M}*m)
    land(d)

a = run(scout, d1)
b = run(follow, d2)
wait(a, b)
'''


class Heard:
    """Every command status the agents publish, heard on the mesh (a peer on bravo's
    router), by command id. An agent sends its recent statuses again when a ground may
    have missed them (the takeover): the same status, its timestamp and all, counts once."""

    def __init__(self) -> None:
        self.statuses: dict[str, list[CommandStatus]] = defaultdict(list)

    def __call__(self, sample: Sample) -> None:
        status = decode_status(sample.payload)
        if isinstance(status, CommandStatus) and status not in self.statuses[status.command_id]:
            self.statuses[status.command_id].append(status)

    def each_run_once(self) -> None:
        """Each command started at most once and ended at most once."""
        for command_id, said in self.statuses.items():
            ends = [s.state for s in said if s.state in ("success", "finish", "failure", "cancel", "stop")]
            assert len(ends) <= 1, (command_id, said)
            assert sum(1 for s in said if s.state == "start") <= 1, (command_id, said)

    def started(self, drone_id: str, command: str) -> list[CommandStatus]:
        return [s for ss in self.statuses.values() for s in ss
                if s.drone_id == drone_id and s.command == command and s.state == "start"]


async def listen(bravo: GroundProcess, heard: Heard) -> ZenohBus:
    mesh = await ZenohBus.open("client", connect=[bravo.endpoint], wait=True)
    mesh.subscribe(Keys().status(), heard, maxsize=100_000)
    return mesh


@dataclass
class Rig:
    alpha: GroundProcess  # to kill
    a: httpx.AsyncClient  # alpha's API
    b: httpx.AsyncClient  # bravo's
    heard: Heard


@asynccontextmanager
async def two_grounds_ready(tmp_path: Path, spawns: dict[str, tuple[float, float]],
                            max_speed: float) -> AsyncIterator[Rig]:
    """Alpha active, bravo standby, a sim agent per spawn ready on both; every status
    heard on the mesh. All stopped at the end, also on failure."""
    alpha, bravo, agents = two_grounds_and_fleet(tmp_path, spawns, max_speed=max_speed)
    heard = Heard()
    mesh: ZenohBus | None = None
    try:
        await alpha.ready()
        await bravo.ready()
        mesh = await listen(bravo, heard)
        async with httpx.AsyncClient(base_url=alpha.url, timeout=10) as a, \
                httpx.AsyncClient(base_url=bravo.url, timeout=10) as b:
            for drone_id in spawns:
                await wait_state(a, drone_id, "ready", 30)
                await wait_state(b, drone_id, "ready", 30)
            await until(lambda: ground_active(a, "alpha"), 20, "alpha active")
            yield Rig(alpha, a, b, heard)
    finally:
        if mesh is not None:
            await mesh.close()
        stop_all([*agents, bravo, alpha])


async def finished_on_bravo_when_killed_at(rig: Rig, script: str, says: str, what: str) -> list[str]:
    """Submit `script` to alpha, kill alpha as soon as the mission's log has a line
    with `says` in it; the mission finishes on bravo from the journal, each command run
    once. Bravo's log of it."""
    mission_id = await submit(rig.a, script, "taken over")

    async def said() -> bool:
        log = (await rig.a.get(f"/mission/{mission_id}")).json()["log"]
        return any(says in line["message"] for line in log)
    await until(said, 90, what)
    rig.alpha.kill()
    await until(lambda: ground_active(rig.b, "bravo"), 10, "bravo active after alpha died")
    taken = f"alpha-{mission_id}"
    done = await ended(rig.b, taken, 120)
    log = [line["message"] for line in (await rig.b.get(f"/mission/{taken}")).json()["log"]]
    assert (done["status"], done["cause"]) == ("finished", "success"), (done, log)
    assert any(m.startswith("Journal taken again") for m in log), log
    rig.heard.each_run_once()
    return log


def took_off(heard: Heard) -> list[str]:
    """The drones that took off, in order, once per takeoff."""
    return [s.drone_id for ss in heard.statuses.values() for s in ss if s.command == "takeoff" and s.state == "start"]


@pytest.mark.slow(60)
async def test_a_mission_goes_on_on_the_standby_when_the_active_ground_is_killed(tmp_path: Path) -> None:
    async with two_grounds_ready(tmp_path, SPAWNS, max_speed=6) as rig:
        alpha, a, b, heard = rig.alpha, rig.a, rig.b, rig.heard
        statuses = heard.statuses  # command id → what its drone said of it
        mission_id = await submit(a, SCRIPT, "durable")

        def moved(drone_id: str) -> int:
            return sum(1 for ss in statuses.values() for s in ss
                       if s.drone_id == drone_id and s.command == "goto" and s.state == "finish")

        await until(lambda: moved("drone01") >= 1, 60, "scout's first leg flown")

        async def journal_copied() -> bool:  # the journal crosses the mesh as it is written
            reply = await b.get(f"/ground/alpha/mission/{mission_id}")
            return reply.status_code == 200 and reply.json()["status"] == "running"
        await until(journal_copied, 10, "the running mission in bravo's copy")
        killed = time.monotonic()
        alpha.kill()
        await until(lambda: ground_active(b, "bravo"), 10, "bravo active after alpha died")
        took_s = time.monotonic() - killed
        assert took_s < 5, f"bravo took {took_s:.1f} s to take over"

        taken = f"alpha-{mission_id}"
        # The id the client holds reaches it on bravo too, and the listing shows both names.
        held = (await b.get(f"/mission/{mission_id}")).json()
        assert (held["mission_id"], held["submitted_as"]) == (taken, mission_id), held
        listed = {m["mission_id"]: m for m in (await b.get("/mission")).json()}
        assert listed[taken]["submitted_as"] == mission_id, listed
        done = await ended(b, taken, 120)
        assert (done["status"], done["cause"]) == ("finished", "success"), done
        messages = [line["message"] for line in (await b.get(f"/mission/{taken}")).json()["log"]]
        assert any(f"Mission {mission_id} of ground alpha goes on here as {taken}" in m for m in messages), messages
        # The log as alpha wrote it, each line once: the replay writes alpha's lines
        # again and bravo keeps only those its copy lacked.
        for line in ("Mission started", "Assigned drone01 (drone 'drone01')", "Assigned drone02 (drone 'drone02')"):
            assert messages.count(line) == 1, messages

        # Each verb's command was run once: one end per command id, none started
        # twice, and four legs each, as if alpha had never died.
        heard.each_run_once()
        assert moved("drone01") == LEGS and moved("drone02") == LEGS, dict(statuses)
        for drone_id in ("drone01", "drone02"):
            legs = [s.coords for s in heard.started(drone_id, "goto")]
            assert len(legs) == LEGS and all(c is not None for c in legs), legs
            start = SPAWNS[drone_id]
            last = legs[-1]
            assert last is not None
            assert distance_m(start[0], start[1], last.lat, last.lon) == pytest.approx(LEGS * LEG_M, abs=2.0)
        assert not [s for ss in statuses.values() for s in ss if s.drone_id == "drone03"], "drone03 was not asked"




REPLACED_LEGS = 6
# drone02 waits where the route ends: at the spot where drone01 is replaced it is 24 m
# from its home, drone01 36 m from its own, so one swap is enough.
REPLACEMENT_SPAWNS = {"drone01": HOME, "drone02": destination(*HOME, REPLACED_LEGS * 10, 0),
                      "drone03": destination(*HOME, 30, 90)}
REPLACEMENT_SCRIPT = f'''d = assign(near(position({HOME[0]}, {HOME[1]})))  # drone01, by where it is: replaceable
enable("replacement", drainage=0.02, min_battery=0.25)
arm(d)
takeoff(d, 6*m)
turn(d, north)
for leg in range({REPLACED_LEGS}):
    move(d, forward=10*m)
land(d)
'''


@pytest.mark.slow(60)
async def test_a_replacement_under_way_goes_on_on_the_standby(tmp_path: Path) -> None:
    """The replacement plugin swaps drone01 once its battery will not bring it home
    (2 % a metre: past about 36 m north); alpha is killed as soon as its log says so,
    while it sends drone01 home and claims drone02. On bravo the replay makes the same
    decision from the same journalled telemetry (the journal went ahead of the log line
    and of the commands: without that, bravo replayed to just before the decision, went
    on live while drone01 flew home, and failed `cmd_exec` sending it a leg once it had
    landed), the swap goes on with nothing started twice, and drone02 flies the
    interrupted leg and the rest."""
    async with two_grounds_ready(tmp_path, REPLACEMENT_SPAWNS, max_speed=8) as rig:
        await finished_on_bravo_when_killed_at(rig, REPLACEMENT_SCRIPT, "to fly home",
                                               "the replacement plugin deciding to swap drone01")
        heard = rig.heard
        # One swap, made once: drone01 then drone02 took off, each once, and drone02
        # flew the last leg to where the plan ends (60 m north of drone01's spawn).
        assert took_off(heard) == ["drone01", "drone02"], took_off(heard)
        legs = [s.coords for s in heard.started("drone02", "goto") if s.coords is not None]
        spawn = REPLACEMENT_SPAWNS["drone01"]
        assert legs and distance_m(spawn[0], spawn[1], legs[-1].lat, legs[-1].lon) == pytest.approx(
            REPLACED_LEGS * 10, abs=3.0), legs


RELAY_SPAWNS = {"drone01": HOME, "drone02": destination(*HOME, 8, 90), "drone03": destination(*HOME, 16, 90)}
RELAYED_SCRIPT = f'''enable("relay", mode="distance", target_dist=12*m, ground=[{HOME[0]}, {HOME[1]}])
d = assign("drone01")
arm(d)
takeoff(d, 6*m)
move(d, forward=24*m, speed=8*m/s)  # past target_dist: a relay follows it
sleep(1*s)
move(d, backward=24*m, speed=8*m/s)
land(d)
'''


@pytest.mark.slow(60)
async def test_a_relay_on_its_way_stays_one_relay_on_the_standby(tmp_path: Path) -> None:
    """The relay plugin sends a relay after drone01 as it flies past `target_dist`
    (distance mode: geometry alone, where loopback's perfect links would give the
    other modes nothing to relay); alpha is killed as soon as its log names the relay.
    On bravo the replay makes the same decision from the same journalled telemetry:
    one relay, which takes off once, follows, and is sent home once, when drone01 is
    back; nothing is started twice."""
    async with two_grounds_ready(tmp_path, RELAY_SPAWNS, max_speed=8) as rig:
        log = await finished_on_bravo_when_killed_at(rig, RELAYED_SCRIPT, "following drone01",
                                                     "the relay plugin sending a relay after drone01")
        heard = rig.heard
        flown = took_off(heard)
        assert len(flown) == 2 and flown[0] == "drone01" and flown[1] in ("drone02", "drone03"), flown
        relay = flown[1]
        assert sum(m.startswith(f"{relay}: following drone01") for m in log) == 1, log
        assert sum(f"{relay}: relay no longer needed, returning" in m for m in log) == 1, log
        assert len(heard.started(relay, "takeoff")) == 1 and len(heard.started(relay, "return")) == 1, dict(heard.statuses)
