"""The relay corpus (issue 32): random worlds from a seed, and the relay plugin on 20
of them in fast time."""

from __future__ import annotations

import asyncio
import math
import re
from typing import Any

import pytest

from dronefleet import relay_corpus as rc
from dronefleet import relay_experiments as rx
from dronefleet.compose import SimField, simulate
from dronefleet.schemas.config_loading import load_config
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.corpus import (
    CROSSING_CLEAR_M,
    CROSSING_SPREAD,
    MIN_BEARING_GAP,
    SPAWN_GAP_M,
    USER_LAYOUTS,
    areas_apart_m,
    generate,
    hop_m,
)
from dronefleet.sim.faults import apply_fault
from dronefleet.sim.world import ROW_SPACING_M, World

SEEDS = range(200)


def test_worlds_cover_what_the_issue_asks_and_replay_from_their_seed() -> None:
    worlds = [generate(seed) for seed in SEEDS]
    assert generate(7) == worlds[7]  # the same seed, the same world
    assert len({w.radio for w in worlds}) == len(worlds)
    for w in worlds:
        r = w.radio
        assert 25 <= r.good_m <= 150 and 1.3 * r.good_m - 0.2 <= r.lost_m <= 2.0 * r.good_m + 0.2, w.describe()
        assert 1 <= len(w.surveys) <= 3 and 2 <= len(w.spares) <= 8
        for s in w.surveys:
            assert 1.2 * r.lost_m - 0.2 <= s.distance_m <= 3.0 * r.lost_m + 0.2
        for i, a in enumerate(w.surveys):
            for b in w.surveys[i + 1:]:
                gap = abs(a.bearing - b.bearing) % 360
                if w.crossing and {a.drone, b.drone} == set(w.workers[:2]):  # a shared way, the areas apart
                    assert min(gap, 360 - gap) <= CROSSING_SPREAD + 0.1 and areas_apart_m(a, b) >= CROSSING_CLEAR_M
                else:
                    assert min(gap, 360 - gap) >= MIN_BEARING_GAP - 0.1
        spots = [(d.lat, d.lon) for d in w.world.spawn() if d.lat is not None and d.lon is not None]
        assert len(spots) == len(w.world.drones)
        gap = ROW_SPACING_M if w.layout in USER_LAYOUTS else SPAWN_GAP_M  # a world file's row: 5 m
        for i, (lat, lon) in enumerate(spots):
            for other in spots[i + 1:]:
                assert distance_m(lat, lon, *other) >= gap - 0.01, w.describe()
        # a chain every hop_m reaches each farthest corner; one relay fewer could not
        for s, chain in zip(w.surveys, w.needs.chains, strict=True):
            assert (chain + 1) * w.needs.hop_m >= s.farthest_m > chain * w.needs.hop_m
        assert w.needs.lower_bound == max(w.needs.chains) and w.needs.enough == sum(w.needs.chains)
    assert {w.layout for w in worlds} == {"row", "grid", "ring", "scatter", "offset", "file-row", "cluster"}
    # the world file's default row stands on the laptop's own spot
    assert any(w.layout == "file-row" and distance_m(w.world.drones[0].lat or 0, w.world.drones[0].lon or 0,
                                                     w.world.origin.lat, w.world.origin.lon) < 0.01 for w in worlds)
    assert 0.2 < sum(w.spares_suffice for w in worlds) / len(worlds) < 0.9
    shared = [w for w in worlds if w.crossing]
    assert 0.1 < len(shared) / len(worlds) < 0.3 and all(len(w.surveys) >= 2 for w in shared)
    assert any(len(w.surveys) == 3 for w in shared) and any(w.spares_suffice for w in shared)
    # the other worlds are drawn as before there were shared ways
    assert all(w == generate(w.seed, shared_ways=False) for w in worlds if not w.crossing)


def test_on_a_shared_way_the_farther_worker_flies_past_the_nearer_ones_area() -> None:
    """The farther worker's way out passes the nearer worker's area on its way, within
    radio range of its centre: the two workers' relays stand among each other."""
    shared = [w for w in map(generate, SEEDS) if w.crossing]
    for w in shared:
        near, far = sorted(w.surveys[:2], key=lambda s: s.distance_m)
        turn = math.radians(abs(near.bearing - far.bearing) % 360)
        along, beside = near.distance_m * math.cos(turn), abs(near.distance_m * math.sin(turn))
        assert along + near.side_m < far.distance_m and beside < w.radio.lost_m, w.describe()


def test_the_lower_bound_uses_the_longest_hop_that_holds_and_keeps_the_min_quality_count() -> None:
    """bench/relay_hop.py: hops losing 10 % keep a static chain's gap under 3 s, longer
    ones do not; the first bound (hops at the plugin's min_quality) is kept beside it."""
    for w in map(generate, SEEDS):
        r = w.radio
        assert hop_m(r) == pytest.approx(r.good_m + 0.1 * (r.lost_m - r.good_m))
        lenient = r.good_m + 0.4 * (r.lost_m - r.good_m)
        assert w.needs.enough_min_quality == sum(max(0, math.ceil(s.farthest_m / lenient) - 1) for s in w.surveys)
        assert w.needs.enough_min_quality <= w.needs.enough


@pytest.mark.slow(5)  # of one core: ordered among the long tests, while cores are idle (ADR 0011)
@pytest.mark.parametrize("seed", range(5))
def test_corpus_worlds_never_fail_through_a_relay(seed: int) -> None:
    """Issue 32 item 2 on the first 5 worlds (the users' worlds are test_relay_repro.py's): a relay on duty is part of the link, so no
    mission fails because a relay's failsafe pulled it off duty or a relay's move was
    refused, and no relay's command is interrupted by its lost-link failsafe. The bench
    holds the same judgement over hundreds of worlds with the rates the issue asks for
    (bench/relay_corpus.py); here, one test per world, so the suite's workers share them
    (each is a few seconds of one core)."""
    world = generate(seed)
    result = asyncio.run(rc.fly(world, "measured"))
    o = rc.judge(world, "measured", result)
    relays = set(result["drones"]) - set(world.workers)
    named = set(re.findall(r"drone\d+", o.message))
    assert not (named & relays) or o.finished, f"{world.describe()}: {o.cause}: {o.message}"
    interrupted = [line["message"] for line in result["log"]
                   if "lost-link failsafe" in line["message"] and line["message"].split(":")[0] in relays]
    assert not interrupted, f"{world.describe()}: {interrupted}"
    assert not math.isnan(o.longest_gap_s), world.describe()


@pytest.mark.slow(15)
@pytest.mark.parametrize("seed", [6, 12, 13, 25])
def test_chain_mode_measures_the_radio_and_keeps_the_worker_heard(seed: int) -> None:
    """Issue 32 items 1 and 3 on four corpus worlds whose spares suffice (radios 69/95,
    105/166, 32/62 and 126/168 m; none given to the plugin, whose prior is 60/100): the
    probe relay measures the hop that
    holds, the worker waits at the chain's edge (said in the log) and flies its survey with
    the ground hearing it at least every 3 s, no two flying drones within 5 m. (Rates over
    many worlds are the bench's: bench/relay_corpus.py --modes chain.)"""
    world = generate(seed)
    assert world.spares_suffice
    result = asyncio.run(rc.fly(world, "chain"))
    o = rc.judge(world, "chain", result)
    log = [line["message"] for line in result["log"]]
    assert o.connected, f"{world.describe()}: {o}"
    assert o.separation_m >= rc.MIN_SEPARATION_M, f"{world.describe()}: {o.separation_m:.1f} m"
    assert any("the radio holds hops of" in m for m in log), log
    assert any("held at the edge of its relay chain" in m for m in log) and any("going on to its goal" in m for m in log)
    learnt = next(float(m.split("hops of ")[1].split(" m")[0]) for m in log if "the radio holds hops of" in m)
    assert learnt <= world.radio.good_m + 0.15 * (world.radio.lost_m - world.radio.good_m), (learnt, world.describe())


@pytest.mark.slow(45)  # of one core, ten drones: 23 CPU-seconds
def test_chain_mode_proves_its_own_hop_past_a_ring_of_spares() -> None:
    """On a radio of 56/107 m with three workers and seven spares in a ring around the
    laptop, the probe's answers came over its own link, so a clean window proves its own
    hop, not the bottleneck through the spare below it (it learnt 40 m so); a relay sent
    home and at once again, armed still after landing, was disarmed before its takeoff
    step, and the plugin sends another instead of waiting for it to the time limit;
    no worker flies over a relay climbing through its level (it came within 1.3 m)."""
    world = generate(63, shared_ways=False)
    assert world.spares_suffice and world.layout == "ring"
    result = asyncio.run(rc.fly(world, "chain"))
    o = rc.judge(world, "chain", result)
    log = [line["message"] for line in result["log"]]
    assert o.finished, f"{world.describe()}: {o}"
    learnt = next(float(m.split("hops of ")[1].split(" m")[0]) for m in log if "the radio holds hops of" in m)
    assert learnt >= 0.9 * world.radio.good_m, (learnt, world.describe())
    assert o.separation_m >= rc.MIN_SEPARATION_M, f"{world.describe()}: {o.separation_m:.1f} m"


@pytest.mark.slow(12)
def test_a_relay_that_cannot_arm_is_replaced_and_not_sent_again_and_again() -> None:
    """Issue 32 item 2: a relay's failure is the plugin's problem. World 6's first spare
    is denied arming by its autopilot (after the ground saw it healthy, so it is
    assigned): sent as the probe it never takes off; the plan gives it up after
    LAUNCH_TIMEOUT_S and sends another, and a drone that failed twice is kept out, not
    sent again and again. The mission finishes with its worker heard."""
    world = generate(6)
    broken = world.spares[0]

    async def fly() -> dict[str, Any]:
        gs = world.world.ground_station
        assert gs is not None and (line := rc.MODES["chain"]) is not None
        sim = SimField(world.world, seed=world.seed)
        try:
            await sim.start()
            # its autopilot refuses to arm from now on; the ground saw it healthy
            apply_fault(sim.vehicles[broken], "arm_denied", "preflight check failed")
            record = await sim.run_mission(world.script(line.format(lat=gs.lat, lon=gs.lon)), max_s=rc.MAX_S)
            return sim.result(record)
        finally:
            await sim.close()

    result = asyncio.run(fly())
    o = rc.judge(world, "chain", result)
    log = [line["message"] for line in result["log"]]
    assert o.connected, f"{world.describe()}: {o}\n" + "\n".join(log)
    gave_up = [m for m in log if m.startswith(f"{broken}: assigned but never took off")]
    assert gave_up and "the plugin sends another relay" in gave_up[0], log
    assert len(gave_up) <= 2 and (len(gave_up) < 2 or "no longer this one" in gave_up[1]), gave_up
    assert broken not in rx.relays_flown(result, world.workers)
    assert any("relay duty" in m and not m.startswith(broken) for m in log), log


def test_chain_mode_where_the_spares_do_not_suffice_holds_then_names_the_relays_missing() -> None:
    """Issue 32's done-when for worlds whose spares do not suffice: the worker is held at
    the chain's edge, never flown out of reach, and the mission ends `requirements`
    naming how many relays its goal still needs."""
    world = generate(1)
    assert not world.spares_suffice
    result = asyncio.run(rc.fly(world, "chain"))
    o = rc.judge(world, "chain", result)
    assert (o.status, o.cause) == ("failed", "requirements"), o
    assert re.search(r"drone\d+ needs \d+ more relay\(s\) to reach its goal and no drone is free", o.message), o.message
    assert o.longest_gap_s < 5.0, o  # held in reach: never the 30 s of link_lost


HELD_LOW = """
enable("relay")
d = assign("drone01")
arm(d)
takeoff(d, 12*m)
move(d, to=position(GOAL_LAT, GOAL_LON, FIELD_ALT))
"""


@pytest.mark.slow(12)
def test_a_goto_held_short_of_a_lower_goal_keeps_its_level() -> None:
    """A worker's goto to a goal at field level (its way home, say), held at the edge
    of its chain: the leg to the edge went down to the field, where the drone could go
    no further, and the mission ran to its time limit. Here the goal is 117 m out on a
    40/70 m radio with one spare, so the worker is held short for good: it waits at
    its level, never down on the field, and the mission ends naming the relays missing."""
    world = load_config(World, None, {
        "origin": {"lat": 40.634125, "lon": -8.660336, "alt": 8.2},
        "ground_station": {"lat": 40.634125, "lon": -8.660336},
        "radio": {"good_m": 40, "lost_m": 70}, "count": 2})
    goal = destination(40.634125, -8.660336, 117.0, 60.0)
    source = HELD_LOW.replace("GOAL_LAT", str(goal[0])).replace("GOAL_LON", str(goal[1])).replace("FIELD_ALT", "8.2")
    result = asyncio.run(simulate(source, world, seed=5, max_s=900, plots=False))
    record = result["mission"]
    assert (record["status"], record["cause"]) == ("failed", "requirements"), record
    away = [q for q in rx.track(result, "drone01") if distance_m(q["lat"], q["lon"], 40.634125, -8.660336) > 15]
    assert away, "drone01 never left the laptop"
    assert min(q["rel_alt"] for q in away) > 10, [round(q["rel_alt"], 1) for q in away][-20:]
