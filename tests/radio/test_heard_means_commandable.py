"""A drone the ground lists as ready answers a command within 3 s (issue 76), on real
packets with the real `fleet ground` and `fleet sim WORLD --agents --radio`: after it
registers through a neighbour, and every time its radio comes back after going silent
long enough for its links to close (the lease is 2 s).

drone01 stands 20 m from the laptop; drone02 55 m out; drone03 beyond drone02, out of
the laptop's reach. A drone's radio is cut by dropping every packet on its interface
inside its namespace (nftables), then restored; its first command once the ground lists
it `ready` again must be answered by its agent within 3 s.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import httpx
import pytest

from tests.harness import ChildProcess, GroundProcess
from tests.radio.emulated import RADIO_A, RadioSim, north, state_is
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.radio]

ANSWER_S = 3.0
CUTS = ("drone01", "drone03", "drone01", "drone03")


def cut(netns: str) -> None:
    rules = ("table inet fleet_cut {\n chain in { type filter hook input priority 0; policy accept; iifname \"radio0\" drop; }\n"
             " chain out { type filter hook output priority 0; policy accept; oifname \"radio0\" drop; }\n}\n")
    subprocess.run(["ip", "netns", "exec", netns, "nft", "-f", "-"], check=True, text=True, input=rules)


def restore(netns: str) -> None:
    subprocess.run(["ip", "netns", "exec", netns, "nft", "delete", "table", "inet", "fleet_cut"], check=True)


async def first_command_s(http: httpx.AsyncClient, drone_id: str) -> float:
    """The drone is listed ready: how long its agent takes to accept `arm` (then disarmed)."""
    start = time.monotonic()
    r = await http.post(f"/drone/{drone_id}/cmd", json={"cmd": "arm"})
    took = time.monotonic() - start
    assert r.status_code == 200, f"{drone_id} listed ready, its first command: {r.status_code} {r.text} after {took:.1f} s"
    r = await http.post(f"/drone/{drone_id}/cmd", json={"cmd": "disarm"})
    assert r.status_code == 200, r.text
    await until(lambda: state_is(http, drone_id, "ready"), 10, f"{drone_id} disarmed")
    return took


@RADIO_A
@pytest.mark.slow(60)
async def test_a_drone_listed_ready_answers_its_first_command_through_a_neighbour_and_after_its_link_comes_back(
        tmp_path: Path, processes: list[ChildProcess]) -> None:
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0")
    processes.append(ground)
    await ground.ready()
    near, mid, far = north(20), north(50), north(105)
    sim = RadioSim(tmp_path, ground, [
        {"id": "drone01", "lat": near[0], "lon": near[1]},
        {"id": "drone02", "lat": mid[0], "lon": mid[1], "roles": ["survey", "relay"]},
        {"id": "drone03", "lat": far[0], "lon": far[1]},
    ], lost_link={"timeout_s": 60, "action": "continue"})
    processes.append(sim)
    await sim.up()
    answers: list[tuple[str, float]] = []
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        # drone03 registers through drone02: commanded as soon as it is listed ready
        await until(lambda: state_is(http, "drone03", "ready"), 60, "drone03 ready at the ground (through drone02)")
        answers.append(("drone03 registered", await first_command_s(http, "drone03")))
        await until(lambda: state_is(http, "drone01", "ready"), 60, "drone01 ready")
        for drone_id in CUTS:
            netns = sim.netns(drone_id)
            cut(netns)
            try:  # its token goes when the lease (2 s) runs out: its links have closed
                await until(lambda d=drone_id: state_is(http, d, "unknown"), 10, f"{drone_id} unknown with its radio cut")
            finally:
                restore(netns)
            await until(lambda d=drone_id: state_is(http, d, "ready"), 30, f"{drone_id} ready again")
            answers.append((f"{drone_id} back", await first_command_s(http, drone_id)))
    print("first commands answered after (s):", [(what, round(s, 2)) for what, s in answers])
    slow = [(what, round(s, 2)) for what, s in answers if s > ANSWER_S]
    assert not slow, f"first commands answered after {ANSWER_S:g} s: {slow} (all: {answers})"
