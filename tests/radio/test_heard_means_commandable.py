"""A drone the ground lists as ready answers a command within 3 s (issue 76), on real
packets with the real `fleet ground` and `fleet sim WORLD --agents --radio`: after it
registers through a neighbour, while the mesh routes it through a neighbour and back,
and after its radio comes back from silence long enough for its links to close (the
lease is 2 s). Cuts are nftables rules inside the drone's namespace.
"""

from __future__ import annotations

import ipaddress
import subprocess
import time
from functools import partial
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.harness import ChildProcess
from tests.radio.emulated import RADIO_B, drone, north, relay_line, state_is
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.radio]

ANSWER_S = 3.0


def cut(netns: str) -> None:
    rules = ("table inet fleet_cut {\n chain in { type filter hook input priority 0; policy accept; iifname \"radio0\" drop; }\n"
             " chain out { type filter hook output priority 0; policy accept; oifname \"radio0\" drop; }\n}\n")
    subprocess.run(["ip", "netns", "exec", netns, "nft", "-f", "-"], check=True, text=True, input=rules)


def restore(netns: str) -> None:
    subprocess.run(["ip", "netns", "exec", netns, "nft", "delete", "table", "inet", "fleet_cut"], check=True)


def ground_address(netns: str) -> str:
    """The laptop's radio address: the first of the drone's /24."""
    out = subprocess.run(["ip", "-n", netns, "-o", "-4", "addr", "show", "radio0"], capture_output=True, text=True,
                         check=True).stdout
    return str(next(ipaddress.ip_interface(out.split(" inet ")[1].split()[0]).network.hosts()))


def cut_from_ground(netns: str, ground: str) -> None:
    """Drop the drone's packets to and from the laptop only: its neighbours still hear it."""
    rules = ("table inet fleet_cut {\n"
             f" chain in {{ type filter hook input priority 0; policy accept; ip saddr {ground} drop; }}\n"
             f" chain out {{ type filter hook output priority 0; policy accept; ip daddr {ground} drop; }}\n}}\n")
    subprocess.run(["ip", "netns", "exec", netns, "nft", "-f", "-"], check=True, text=True, input=rules)


@RADIO_B
@pytest.mark.slow(35)
async def test_a_drone_listed_ready_answers_commands_through_a_neighbour_rerouted_and_back_from_silence(
        tmp_path: Path, processes: list[ChildProcess]) -> None:
    """drone01 20 m from the laptop, drone02 50 m out, drone03 beyond drone02 (out of
    the laptop's reach). drone03's first command once listed ready; drone01's hop to the
    laptop cut (drone02 still hears it), two commands once the ground hears it through
    drone02, then its hop restored, two more once heard over it again; then drone03's
    radio silent until the ground has lost it, and its first command once listed ready
    again. Every one is answered by the agent within 3 s.

    Not judged: a command sent in the lease after a silent cut (2 s, ADR 0003), while
    the ground cannot yet know and still lists the drone ready; it waits for the
    failover (2.0 s idle, 2.7 s once under a fresh clone's suite)."""
    ground, sim = await relay_line(tmp_path, processes, north(20), north(50), north(105))
    netns = sim.netns("drone01")
    laptop = ground_address(netns)
    answers: list[tuple[str, int, float, str]] = []  # (what, status, seconds, body)
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:

        async def commanded(what: str, drone_id: str, cmd: str = "disarm") -> None:
            await until(partial(state_is, http, drone_id, "ready"), 30, f"{drone_id} ready ({what})")
            sent = time.monotonic()
            r = await http.post(f"/drone/{drone_id}/cmd", json={"cmd": cmd})
            answers.append((f"{drone_id} {what}", r.status_code, time.monotonic() - sent, r.text))

        await until(partial(state_is, http, "drone03", "ready"), 60, "drone03 ready at the ground (through drone02)")
        await commanded("registered through drone02", "drone03")
        await until(partial(state_is, http, "drone01", "ready"), 60, "drone01 ready")
        cut_from_ground(netns, laptop)
        try:
            await until(partial(hops_are, http, "drone01", 2), 30, "drone01 heard through drone02")
            for _ in range(2):
                await commanded("through drone02", "drone01")
        finally:
            restore(netns)
        await until(partial(hops_are, http, "drone01", 1), 30, "drone01 heard over its own hop again")
        for _ in range(2):
            await commanded("over its own hop again", "drone01")
        cut(sim.netns("drone03"))
        try:  # its token goes when the lease (2 s) runs out: its links have closed
            await until(partial(state_is, http, "drone03", "unknown"), 10, "drone03 unknown with its radio cut")
        finally:
            restore(sim.netns("drone03"))
        await commanded("back through drone02", "drone03")
    print("commands (what, status, s):", [(what, status, round(took, 2)) for what, status, took, _ in answers])
    # Answered by its agent: accepted, or refused by it (a disarm of a disarmed drone); 504 is no answer
    slow = [(what, status, body, round(took, 2)) for what, status, took, body in answers
            if status not in (200, 409) or took > ANSWER_S or "drone state is" in body]
    assert not slow, f"listed ready, not answered within {ANSWER_S:g} s: {slow}"


def grown(items: list[Any], n: int) -> bool:
    return len(items) >= n


async def hops_are(http: httpx.AsyncClient, drone_id: str, hops: int) -> bool:
    """The drone's link report: its probes' answers came over its own hop (1) or through others (2)."""
    d = await drone(http, drone_id)
    link = (d or {}).get("info", {}).get("link") or {}
    return bool(link.get("hops") == hops)
