"""Healthy drones beside failing neighbours, over random scenarios on real packets (issue 57).

Each scenario is drawn from its seed: 3-6 drones on the emulated radio at random
bearings and distances — *healthy* ones whose own hop to the laptop stays in good
range, *failing* neighbours (one or two) near the edge of range, and sometimes a drone
beyond a failing neighbour, reachable only through it — and each failing neighbour
fails in a random way: flying out past the edge and back (a task bundle, twice),
flapping across the edge (short legs, four times), a loss ramp set directly on its
radio (0 to 90 % of packets dropped over 20 s where it stands, held 5 s, then cleared;
nftables in its namespace, whatever the distance says), frozen (its agent and sensors
SIGSTOPped for 20 s), or out of range and back: every packet of its radio dropped
for 3-12 s, twice (its links close: the lease is 2 s), which a drone beyond it shares. The laptop is the real `fleet ground`; the drones are `fleet sim
WORLD --agents --radio`.

For every healthy drone it measures, at the ground: the longest telemetry gap (5 Hz),
liveliness token losses, `Link lost` lines and `unknown` states. For every drone, a
command (`arm`) sent as soon as it first appears in `GET /drone` must be answered by
its agent within 3 s (through neighbours too), and so must the first query to its
agent each time the ground lists it ready, hold or active again after `unknown` or
`unreachable` once its failure (or that of the neighbour it is reached through) is
over: its link came back (a read of a bundle record, which changes nothing: 200 or the
agent's 404 is an answer, 504 is none). Listed again while a failure goes on (a sample
through a hop losing 90 %) is counted apart and not judged. Needs CAP_NET_ADMIN (root).

    .venv/bin/python bench/mesh_corpus.py [--scenarios 50] [--seed 0] [--keep DIR]

Prints one line per scenario and the rates; exits 1 if any healthy drone went 1.5 s
unheard, lost its token, was logged `Link lost` or shown `unknown` or `unreachable`, or any first
command, at registration or back, was not answered within 3 s.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import itertools
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx  # noqa: E402

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.port import Sample  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.geo import destination  # noqa: E402
from dronefleet.sim.radio import RadioModel  # noqa: E402
from dronefleet.sim.radio_net import has_net_admin  # noqa: E402
from tests.harness import GroundProcess, stop_all  # noqa: E402
from tests.radio.emulated import GROUND, RadioSim  # noqa: E402

GAP_S = 1.5
COMMAND_S = 3.0
FAILURES = ("flyout", "flapping", "ramp", "frozen", "outage")
OUTAGE_S = (3.0, 12.0)  # how long an outage drops every packet of the drone's radio
RAMP = (20.0, 900, 5.0)  # seconds to ramp, loss at the top (1/1000ths), seconds held there
FROZEN_S = 20.0
WATCH_S = 45.0  # at most this long for the failures to play out


@dataclass
class Drone:
    id: str
    bearing: float
    distance_m: float
    role: str  # healthy | failing | beyond
    failure: str | None = None

    def spot(self, distance_m: float | None = None) -> tuple[float, float]:
        return destination(GROUND[0], GROUND[1], self.distance_m if distance_m is None else distance_m, self.bearing)


@dataclass
class Scenario:
    seed: int
    radio: RadioModel
    drones: list[Drone] = field(default_factory=list)

    def describe(self) -> str:
        parts = [f"{d.id} {d.role}{'/' + d.failure if d.failure else ''} {d.distance_m:.0f} m@{d.bearing:.0f}°"
                 for d in self.drones]
        return f"radio {self.radio.good_m:.0f}/{self.radio.lost_m:.0f} m: " + ", ".join(parts)


def scenario(seed: int) -> Scenario:
    """3-6 drones: 1-2 failing neighbours, the rest healthy, sometimes one beyond a
    failing neighbour (it counts among the 3-6)."""
    rng = random.Random(seed)
    good = rng.uniform(40, 80)
    radio = RadioModel(good_m=round(good), lost_m=round(good * rng.uniform(1.5, 1.8)))
    n = rng.randint(3, 6)
    failing = rng.randint(1, min(2, n - 1))
    beyond = 1 if n - failing >= 2 and rng.random() < 0.5 else 0
    drones: list[Drone] = []
    for _ in range(failing):
        drones.append(Drone(f"drone{len(drones) + 1:02d}", rng.uniform(0, 360), rng.uniform(0.6, 0.9) * radio.good_m,
                            "failing", rng.choice(FAILURES)))
    if beyond:
        host = drones[0]
        drones.append(Drone(f"drone{len(drones) + 1:02d}", host.bearing, radio.lost_m + rng.uniform(2, 10), "beyond"))
    while len(drones) < n:
        drones.append(Drone(f"drone{len(drones) + 1:02d}", rng.uniform(0, 360),
                            rng.uniform(10, 0.85 * math.sqrt(max(0.0, radio.good_m**2 - 100))), "healthy"))
    return Scenario(seed, radio, drones)


@dataclass
class Outcome:
    gaps: dict[str, float]  # healthy drone -> longest gap at the ground (s)
    gap_at: dict[str, float]  # healthy drone -> when that gap began (s into the failures)
    # healthy drone -> how long the sample that ended its longest gap had been on its way
    # (about the gap: it was held on the way; near zero: the drone published nothing)
    gap_transit: dict[str, float]
    token_losses: dict[str, int]
    link_lost: dict[str, int]
    unknown: dict[str, int]
    first_command_s: dict[str, float | None]  # every drone: how long its first command took (None: not answered)
    back_s: list[tuple[str, float | None]]  # each time a drone was listed commandable again, its failure over: first answer (s)
    flicker_s: list[tuple[str, float | None]]  # the same while its failure (or its only neighbour's) still went on
    arrivals: dict[str, list[tuple[float, float]]]  # healthy drones: each sample's arrival (s into the watch), s on its way


async def run(sc: Scenario, tmp: Path) -> Outcome:
    healthy = [d.id for d in sc.drones if d.role == "healthy"]
    started: list[Any] = []
    heard: dict[str, list[tuple[float, float]]] = {d: [] for d in healthy}  # (arrived, s on its way)
    tokens: dict[str, int] = dict.fromkeys(healthy, 0)
    unknown: dict[str, int] = dict.fromkeys(healthy, 0)
    first: dict[str, float | None] = {}
    back: list[tuple[str, float | None]] = []
    flicker: list[tuple[str, float | None]] = []
    failing: set[str] = set()  # the drones whose failure goes on now
    host = {d.id: sc.drones[0].id for d in sc.drones if d.role == "beyond"}  # reached only through it

    def still_failing(drone_id: str) -> bool:
        return drone_id in failing or host.get(drone_id) in failing

    try:
        ground = GroundProcess(tmp, zenoh_host="0.0.0.0")
        started.append(ground)
        await ground.ready()
        world_drones = [{"id": d.id, "lat": d.spot()[0], "lon": d.spot()[1],
                         **({"roles": ["survey", "relay"]} if d.role == "failing" else {})} for d in sc.drones]
        sim = RadioSim(tmp, ground, world_drones, {"radio": {"good_m": sc.radio.good_m, "lost_m": sc.radio.lost_m}},
                       lost_link={"timeout_s": 60, "action": "continue"})
        started.append(sim)
        await sim.up()
        watcher = await ZenohBus.open("client", [f"tcp/127.0.0.1:{ground.zenoh_port}"])
        try:
            for d in healthy:
                watcher.subscribe(f"drone/{d}/telem", functools.partial(_arrived, heard[d]))
            watcher.watch_liveliness("drone/*/alive", lambda key, alive: _token(tokens, key, alive))
            async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
                await _first_commands(http, [d.id for d in sc.drones], first, deadline_s=90)
                start = time.monotonic()
                poll = asyncio.ensure_future(_watch_states(http, healthy, unknown, [d.id for d in sc.drones],
                                                           still_failing, back, flicker))
                try:
                    await _fail(http, sim, sc, failing)
                finally:
                    poll.cancel()
                end = time.monotonic()
                lost = {d: sum("Link lost" in line for line in await _lines(http, d)) for d in healthy}
        finally:
            await watcher.close()
    finally:
        stop_all(reversed(started))
    gaps, gap_at, gap_transit = {}, {}, {}
    for d in healthy:
        during = [(start, 0.0), *((t, w) for t, w in heard[d] if start <= t <= end), (end, 0.0)]
        gaps[d], gap_at[d], gap_transit[d] = max((b - a, a - start, w) for (a, _), (b, w) in itertools.pairwise(during))
    arrivals = {d: [(round(t - start, 3), round(w, 3)) for t, w in heard[d]] for d in healthy}
    return Outcome(gaps, gap_at, gap_transit, tokens, lost, unknown, first, back, flicker, arrivals)


def _arrived(times: list[tuple[float, float]], sample: Sample) -> None:
    """When a telemetry sample arrived, and how long after the drone stamped it (one
    machine, one clock)."""
    arrived, now = time.monotonic(), time.time()
    try:
        stamped = json.loads(sample.payload)["timestamp"] / 1000
    except (ValueError, KeyError, TypeError):
        stamped = now
    times.append((arrived, now - stamped))


def _token(tokens: dict[str, int], key: str, alive: bool) -> None:
    drone_id = key.split("/")[1]
    if drone_id in tokens and not alive:
        tokens[drone_id] += 1


async def _lines(http: httpx.AsyncClient, drone_id: str) -> list[str]:
    return (await http.get("/drone/logs", params={"drone_id": drone_id})).text.splitlines()


async def _watch_states(http: httpx.AsyncClient, ids: list[str], unknown: dict[str, int], everyone: list[str],
                        still_failing: Callable[[str], bool], back: list[tuple[str, float | None]],
                        flicker: list[tuple[str, float | None]]) -> None:
    """Count each healthy drone's flips to `unknown` or `unreachable` at the ground (twice
    a second), and each time any drone is listed commandable again after `unknown` or
    `unreachable`, time the first answer of its agent: in `back` once its failure is
    over (its link came back), in `flicker` while it goes on (a sample through a hop
    losing 90 %)."""
    was = dict.fromkeys(ids, False)
    away = dict.fromkeys(everyone, False)
    probes: set[asyncio.Task[None]] = set()
    try:
        while True:
            for view in (await http.get("/drone")).json():
                info = view.get("info") or {}
                d, state = info.get("drone_id"), info.get("state")
                if d in was:
                    now = state in ("unknown", "unreachable")
                    unknown[d] += now and not was[d]
                    was[d] = now
                if d in away:
                    if state in ("unknown", "unreachable"):
                        away[d] = True
                    elif away[d] and state in COMMANDABLE:
                        away[d] = False
                        probe = asyncio.ensure_future(_answered_back(http, d, flicker if still_failing(d) else back))
                        probes.add(probe)
                        probe.add_done_callback(probes.discard)
            await asyncio.sleep(0.5)
    finally:
        if probes:
            await asyncio.wait(probes, timeout=COMMAND_S + 2)


COMMANDABLE = ("ready", "hold", "active")


async def _answered_back(http: httpx.AsyncClient, d: str, back: list[tuple[str, float | None]]) -> None:
    """The drone is listed commandable again: a query to its agent that changes nothing
    (a bundle record it never had), timed. The agent's 404 is an answer; 504 is none."""
    sent = time.monotonic()
    r = await http.get(f"/drone/{d}/bundle/reach-probe")
    took = time.monotonic() - sent
    answered = r.status_code == 200 or (r.status_code == 404 and "registered" not in r.text)
    back.append((d, took if answered else None))
    if not answered:
        print(f"  {d} listed commandable again; its agent: {r.status_code} after {took:.1f} s: {r.text}", flush=True)


async def _first_commands(http: httpx.AsyncClient, ids: list[str], first: dict[str, float | None],
                          deadline_s: float) -> None:
    """As each drone first appears in GET /drone, send it `arm` and time the answer."""
    end = time.monotonic() + deadline_s
    while len(first) < len(ids) and time.monotonic() < end:
        listed = {v["info"]["drone_id"] for v in (await http.get("/drone")).json() if v.get("info")}
        for d in ids:
            if d in listed and d not in first:
                sent = time.monotonic()
                r = await http.post(f"/drone/{d}/cmd", json={"cmd": "arm"})
                took = time.monotonic() - sent
                # 409 from the ground (not ready yet) is no answer from the agent: try again
                if r.status_code == 200 or (r.status_code == 409 and "agent" in r.text):
                    first[d] = took
                elif r.status_code == 504:
                    first[d] = None
                    print(f"  {d}'s first command: {r.status_code} after {took:.1f} s: {r.text}", flush=True)
        await asyncio.sleep(0.1)
    for d in ids:
        first.setdefault(d, None)


async def _fail(http: httpx.AsyncClient, sim: RadioSim, sc: Scenario, failing: set[str]) -> None:
    tasks = [asyncio.ensure_future(_one(http, sim, sc, d, failing)) for d in sc.drones if d.role == "failing"]
    try:
        await asyncio.wait_for(asyncio.gather(*tasks), WATCH_S + 60)
    finally:
        for t in tasks:
            t.cancel()


async def _one(http: httpx.AsyncClient, sim: RadioSim, sc: Scenario, d: Drone, failing: set[str]) -> None:
    failing.add(d.id)
    try:
        await _play(http, sim, sc, d, failing)
    finally:
        failing.discard(d.id)


async def _play(http: httpx.AsyncClient, sim: RadioSim, sc: Scenario, d: Drone, failing: set[str]) -> None:
    """The drone's failure; `d.id` leaves `failing` once its link is whole again."""
    if d.failure == "frozen":
        pids = subprocess.run(["ip", "netns", "pids", sim.netns(d.id)], capture_output=True, text=True).stdout.split()
        for pid in pids:
            os.kill(int(pid), signal.SIGSTOP)
        try:
            await asyncio.sleep(FROZEN_S)
        finally:
            for pid in pids:
                os.kill(int(pid), signal.SIGCONT)
            failing.discard(d.id)
        await asyncio.sleep(5)
        return
    if d.failure == "ramp":
        await _ramp(sim.netns(d.id), failing, d.id)
        return
    if d.failure == "outage":
        rng = random.Random(f"{sc.seed} {d.id}")
        for _ in range(2):
            failing.add(d.id)
            await _outage(sim.netns(d.id), rng.uniform(*OUTAGE_S))
            failing.discard(d.id)
            await asyncio.sleep(8)  # back: listed again, and its first answer timed
        return
    if d.failure == "flyout":
        out = [d.spot(sc.radio.lost_m * 0.95), d.spot()] * 2
    else:  # flapping: short legs across the edge of good range
        out = [d.spot(sc.radio.good_m * 1.25), d.spot(sc.radio.good_m * 0.9)] * 4
    bundle = {"on_link_loss": "continue", "timeout_s": 300, "steps": [
        {"cmd": "takeoff", "alt": 10}, *({"cmd": "goto", "lat": p[0], "lon": p[1], "speed": 8} for p in out)]}
    await http.post(f"/drone/{d.id}/cmd", json={"cmd": "arm"})
    r = await http.post(f"/drone/{d.id}/bundle", json=bundle)
    if r.status_code != 200:
        raise ScenarioFailed(f"seed {sc.seed}: {d.id}'s bundle refused: {r.text}")
    bundle_id = r.json()["bundle_id"]
    end = time.monotonic() + WATCH_S + 50
    while time.monotonic() < end:
        rec = await http.get(f"/drone/{d.id}/bundle/{bundle_id}")
        if rec.status_code == 200 and rec.json()["state"] != "running":
            return
        await asyncio.sleep(1.0)


async def _ramp(netns: str, failing: set[str], drone_id: str) -> None:
    """Drop a rising share of everything in and out of the drone's radio, then clear it."""
    ramp_s, top, hold_s = RAMP

    def loss(k: int) -> None:
        rules = "" if k <= 0 else "".join(
            f"add rule inet fleet_ramp {hook} {side} \"radio0\" numgen random mod 1000 < {k} drop\n"
            for hook, side in (("in", "iifname"), ("out", "oifname")))
        subprocess.run(["ip", "netns", "exec", netns, "nft", "-f", "-"], check=True, text=True, input=(
            "table inet fleet_ramp {}\ndelete table inet fleet_ramp\n"
            "table inet fleet_ramp {\n chain in { type filter hook input priority 0; policy accept; }\n"
            " chain out { type filter hook output priority 0; policy accept; }\n}\n" + rules))

    try:
        steps = 20
        for i in range(1, steps + 1):
            loss(round(top * i / steps))
            await asyncio.sleep(ramp_s / steps)
        await asyncio.sleep(hold_s)
    finally:
        loss(0)
        failing.discard(drone_id)
    await asyncio.sleep(5)


async def _outage(netns: str, seconds: float) -> None:
    """Drop every packet in and out of the drone's radio for `seconds`, then clear it."""
    subprocess.run(["ip", "netns", "exec", netns, "nft", "-f", "-"], check=True, text=True, input=(
        "table inet fleet_outage {\n chain in { type filter hook input priority 0; policy accept; iifname \"radio0\" drop; }\n"
        " chain out { type filter hook output priority 0; policy accept; oifname \"radio0\" drop; }\n}\n"))
    try:
        await asyncio.sleep(seconds)
    finally:
        subprocess.run(["ip", "netns", "exec", netns, "nft", "delete", "table", "inet", "fleet_outage"], check=True)


async def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0, help="the first scenario's seed")
    parser.add_argument("--keep", type=Path, metavar="DIR",
                        help="keep a failed scenario's ground, sim and agent logs and the healthy drones' "
                             "arrival times in DIR/seed-N (a passing one's are removed)")
    args = parser.parse_args()
    if not has_net_admin():
        raise ScenarioFailed("the emulated radio needs CAP_NET_ADMIN (run as root)")
    healthy_ok = healthy_all = commands_ok = commands_all = back_ok = back_all = flicker_ok = flicker_all = 0
    worst_gap = 0.0
    for seed in range(args.seed, args.seed + args.scenarios):
        sc = scenario(seed)
        if args.keep is None:
            with tempfile.TemporaryDirectory(prefix="mesh-corpus-") as tmp:
                out = await run(sc, Path(tmp))
        else:
            kept = args.keep / f"seed-{seed}"
            shutil.rmtree(kept, ignore_errors=True)
            kept.mkdir(parents=True)
            out = await run(sc, kept)
        bad = [d for d in out.gaps if out.gaps[d] >= GAP_S or out.token_losses[d] or out.link_lost[d] or out.unknown[d]]
        slow = [d for d, s in out.first_command_s.items() if s is None or s > COMMAND_S]
        slow_back = [(d, s) for d, s in out.back_s if s is None or s > COMMAND_S]
        flicker_all += len(out.flicker_s)
        flicker_ok += sum(1 for _, s in out.flicker_s if s is not None and s <= COMMAND_S)
        if args.keep is not None:
            if bad or slow or slow_back:
                (kept / "arrivals.json").write_text(json.dumps(out.arrivals))
                print(f"  kept in {kept}", flush=True)
            else:
                shutil.rmtree(kept)
        healthy_all += len(out.gaps)
        healthy_ok += len(out.gaps) - len(bad)
        commands_all += len(out.first_command_s)
        commands_ok += len(out.first_command_s) - len(slow)
        back_all += len(out.back_s)
        back_ok += len(out.back_s) - len(slow_back)
        worst_gap = max([worst_gap, *out.gaps.values()])
        gaps = ", ".join(f"{d} {g:.2f} s (at {out.gap_at[d]:.0f} s, the next {out.gap_transit[d]:.2f} s on its way)"
                         for d, g in out.gaps.items())
        slow_text = ", ".join(f"{d} ({'no answer' if out.first_command_s[d] is None else f'{out.first_command_s[d]:.1f} s'})"
                              for d in slow)
        print(f"seed {seed}: {sc.describe()}; healthy gaps {gaps}; "
              f"{'ok' if not bad else 'FAILED ' + ', '.join(bad)}; first commands "
              f"{'ok' if not slow else 'SLOW ' + slow_text}; back and commandable {len(out.back_s)}: "
              f"{'ok' if not slow_back else 'SLOW ' + str(slow_back)}", flush=True)
    print(f"healthy drones kept heard (gap < {GAP_S:g} s, no token lost, no Link lost, never unknown or unreachable): "
          f"{healthy_ok} of {healthy_all}; longest gap {worst_gap:.2f} s; first commands answered within "
          f"{COMMAND_S:g} s: {commands_ok} of {commands_all}; first answers once listed commandable again within "
          f"{COMMAND_S:g} s: {back_ok} of {back_all} (while a failure still went on, not judged: {flicker_ok} of "
          f"{flicker_all})", flush=True)
    return 0 if healthy_ok == healthy_all and commands_ok == commands_all and back_ok == back_all else 1


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
