"""Relay mode "chain" as pure logic (issue 32, relay/chain.py): the hop a probe proves,
the chains laid on it, and the leash on the drones they serve."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dronefleet.relay.chain import (
    DWELL_S,
    LAUNCH_TIMEOUT_S,
    MARGIN,
    PROBE,
    PROVEN_LOSS,
    STRETCH_AFTER_S,
    ChainPlan,
    Chains,
    Seen,
    Worker,
    dist,
    flat,
)
from dronefleet.relay.hop import CONVERGED, FLOOR_M, GROWTH, Reach, bottleneck
from dronefleet.relay.rules import Separation
from dronefleet.relay.ways import segment_distance
from dronefleet.sim.radio import HOLDING_LOSS

DUTY = 21.0  # relays' altitude above the laptop; the worker flies at 15 m


def at(metres: float, bearing_deg: float = 0.0) -> tuple[float, float]:
    b = math.radians(bearing_deg)
    return metres * math.cos(b), metres * math.sin(b)


def test_the_reach_tries_the_model_first_then_grows_and_halves_until_bracketed() -> None:
    r = Reach()
    assert r.trial(60.0) == 60.0 and r.lo == FLOOR_M
    r.held(60.0)
    assert r.trial(60.0) == pytest.approx(60.0 * GROWTH)  # the model's figure is tried once
    r.failed(90.0)
    assert r.trial() == pytest.approx(75.0)
    r.held(75.0)
    r.failed(78.0)
    assert r.known and r.lo == 75.0 and r.hi == 78.0
    assert Reach(lo=50.0, hi=60.0).known is False and Reach(lo=50.0, hi=50.0 * CONVERGED).known


def test_a_failure_shorter_than_what_held_teaches_nothing() -> None:
    r = Reach(lo=50.0)
    r.failed(40.0)
    assert r.hi is None


def test_the_bottleneck_is_the_least_longest_hop_to_the_laptop() -> None:
    # straight to the laptop, 50 m; through a drone standing 20 m out, the longest hop is 30 m
    assert bottleneck((at(50), 0.0), []) == pytest.approx(50.0)
    assert bottleneck((at(50), 0.0), [(at(20), 0.0)]) == pytest.approx(30.0)
    assert bottleneck((at(50), 0.0), [(at(20, 180), 0.0)]) == pytest.approx(50.0)  # behind the laptop: no help
    assert bottleneck((at(40), 30.0), []) == pytest.approx(50.0)  # 3-D


def seen(where: tuple[float, float], alt: float = DUTY, loss: float | None = 0.0, rtt: float | None = 4.0,
         fresh: bool = True) -> Seen:
    return Seen(where, alt, loss, rtt, fresh)


def probe_round(c: Chains, now: float, worker: Worker, **window: object) -> ChainPlan:
    """One measured trial: the probe reports from its spot for a whole window; the plan
    that measured it (and sent the next trial, if any)."""
    assert c.probe is not None and c.probe.relay is not None
    relay, spot = c.probe.relay, c.probe.spot
    c.plan(now, [worker], {relay: seen(spot, **window)}, spare=3)  # type: ignore[arg-type]
    return c.plan(now + DWELL_S + 1, [worker], {relay: seen(spot, **window)}, spare=3)  # type: ignore[arg-type]


def test_a_probe_measures_the_hop_then_chains_are_laid_on_it_and_the_worker_is_leashed() -> None:
    c = Chains(DUTY, first_trial=60.0)
    w = Worker("d1", at(10), 15.0, at(200))
    out = c.plan(0.0, [w], {}, spare=3)
    assert [d[0] for d in out.dispatch] == [PROBE] and c.stuck == {}
    assert math.hypot(dist(out.dispatch[0][1], (0, 0)), DUTY) == pytest.approx(60.0)  # the model's range, in 3-D
    # held near the laptop meanwhile: at most the floor from it
    edge = c.allowed("d1", w.at, w.alt, w.goal)  # type: ignore[arg-type]
    assert math.hypot(dist(edge, (0, 0)), 15.0) <= FLOOR_M * MARGIN + 0.5
    c.joined(PROBE, "r1")
    out = probe_round(c, 10.0, w)  # 60 m held
    assert c.reach.lo == pytest.approx(60.0)
    (relay, spot, back), = out.moves  # the next trial, coming back to the proven spot after its window
    assert relay == "r1" and back > DWELL_S and math.hypot(dist(spot, (0, 0)), DUTY) == pytest.approx(90.0)
    probe_round(c, 40.0, w, loss=0.2, rtt=300.0)  # 90 m does not hold
    assert c.reach.hi == pytest.approx(90.0)
    for now, ok in ((70.0, True), (100.0, False), (130.0, True), (160.0, False), (190.0, True)):
        probe_round(c, now, w, **({} if ok else {"loss": 0.1}))
        if c.reach.known:
            break
    assert c.reach.known and 70.0 < c.reach.lo < 90.0
    hop = c.reach.lo * MARGIN
    # the probe becomes the chain's first relay; the next one is asked for once it is on its way
    out = c.plan(250.0, [w], {"r1": seen(c.safe or (0, 0))}, spare=3)
    (relay, first, back), = out.moves
    assert out.dispatch == []  # not while a relay is sent across in the same plan
    (key, second, _, _), = c.plan(251.0, [w], {"r1": seen(c.safe or (0, 0))}, spare=3).dispatch
    assert relay == "r1" and back == 0 and math.hypot(dist(first, (0, 0)), DUTY) == pytest.approx(hop, abs=0.5)
    assert key == "d1#1" and dist(first, second) == pytest.approx(hop, abs=0.5)
    c.joined(key, "r2")
    assert c.plan(251.0, [w], {"r1": seen(first)}, spare=2).dispatch == []  # r2 flies there; the goal is covered
    # while r2 flies, the worker may go as far as r1 covers, not to the goal
    edge = c.allowed("d1", w.at, w.alt, w.goal)  # type: ignore[arg-type]
    assert math.hypot(dist(edge, first), 15.0 - DUTY) <= hop + 0.5 and dist(edge, w.goal) > 50  # type: ignore[arg-type]
    c.plan(280.0, [w], {"r1": seen(first), "r2": seen(second)}, spare=2)
    assert c.allowed("d1", w.at, w.alt, at(150)) == at(150)  # covered all the way: no leash


@pytest.mark.parametrize(("losses", "held"), [
    ((0.0, 0.06, 0.02, 0.04, 0.0, 0.02, 0.04, 0.02, 0.0, 0.06), True),  # reports over PROVEN_LOSS, 2.6 % on average: it holds
    ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), True),
    ((0.08, 0.04, 0.1, 0.06, 0.08, 0.04, 0.1, 0.06, 0.08, 0.04), False),  # 7 % on average: bounds it
])
def test_a_probe_proves_its_hop_on_the_loss_it_measured_over_its_dwell(losses: tuple[float, ...], held: bool) -> None:
    """The loss reports made on the spot decide, on average: one train's few lost
    datagrams at the edge of good range do not fail a hop, a steady loss does."""
    c = Chains(DUTY, first_trial=60.0)
    w = Worker("d1", at(10), 15.0, at(200))
    c.plan(0.0, [w], {}, spare=3)
    c.joined(PROBE, "r1")
    assert c.probe is not None
    spot = c.probe.spot
    c.plan(5.0, [w], {"r1": seen(spot, loss=0.3)}, spare=3)  # arrived: what it measured on its way does not count
    for k, loss in enumerate(losses, 1):
        c.plan(5.0 + k * DWELL_S / len(losses) + 0.1, [w], {"r1": seen(spot, loss=loss)}, spare=3)
    assert (sum(losses) / len(losses) <= PROVEN_LOSS) is held
    assert (c.reach.lo == pytest.approx(60.0)) is held and (c.reach.hi == pytest.approx(60.0)) is not held
    assert c.reach.holds == pytest.approx(60.0)  # every one of these windows lost less than a 3-s gap allows


def test_a_window_losing_more_than_a_3s_gap_allows_proves_no_holding_hop() -> None:
    c = Chains(DUTY, first_trial=60.0)
    w = Worker("d1", at(10), 15.0, at(200))
    c.plan(0.0, [w], {}, spare=3)
    c.joined(PROBE, "r1")
    probe_round(c, 5.0, w, loss=HOLDING_LOSS * 1.5)
    assert c.reach.hi == pytest.approx(60.0) and c.reach.holds == FLOOR_M


def test_no_free_drone_for_the_chain_is_named_with_the_relays_missing() -> None:
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0)
    w = Worker("d1", at(10), 15.0, at(300))
    out = c.plan(0.0, [w], {}, spare=0)
    assert out.dispatch == [] and "d1 needs" in c.stuck["d1"] and "no drone is free" in c.stuck["d1"]
    needed = int(c.stuck["d1"].split("needs ")[1].split()[0])
    assert needed == math.ceil((300 - 0) / (50 * MARGIN)) - 1 or needed == math.ceil(300 / (50 * MARGIN))


@pytest.mark.parametrize("beyond_m", [-2.0, 2.0])
def test_a_chain_out_of_relays_stretches_to_the_hop_that_held_and_no_further(beyond_m: float) -> None:
    """No drone is free and the goal lies past the chain's hop but within hops a window
    measured to keep a 3-s gap: the chain's relay moves out to such a hop and the worker
    goes on instead of being held; a step further, it is held and named with the relay
    it lacks, and no relay moves."""
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0, holds=56.0)
    (key, spot, _, _), = c.plan(0.0, [Worker("d1", at(5), 15.0, at(60))], {}, spare=1).dispatch
    c.joined(key, "r1")
    stretch = 56.0 * MARGIN
    goal = at(flat(stretch, DUTY) + flat(stretch, DUTY - 15.0) + beyond_m)
    w = Worker("d1", at(5), 15.0, goal)
    assert c.plan(60.0, [w], {"r1": seen(spot)}, spare=0).moves == [] and "d1" in c.stuck  # a drone may come free
    out = c.plan(60.0 + STRETCH_AFTER_S, [w], {"r1": seen(spot)}, spare=0)
    if beyond_m < 0:
        (relay, moved, _), = out.moves
        assert relay == "r1" and c.stuck == {}
        # the shortest hop that reaches the goal: 2 m short of the longest, about 1 m on each of the two hops
        assert stretch - 2.0 < math.hypot(dist(moved, (0, 0)), DUTY) < stretch - 0.5
        c.plan(100.0, [w], {"r1": seen(moved)}, spare=0)
        assert c.stuck == {} and c.allowed("d1", w.at, w.alt, goal) == goal
    else:
        assert out.moves == [] and "d1 needs 1 more relay" in c.stuck["d1"]
        assert dist(c.allowed("d1", w.at, w.alt, goal), goal) > 1.0


def test_relays_go_home_from_the_far_end_once_the_worker_no_longer_needs_them() -> None:
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0)
    far = Worker("d1", at(100), 15.0, at(120))
    out = c.plan(0.0, [far], {}, spare=5)
    c.joined(out.dispatch[0][0], "r1")
    spots = [out.dispatch[0][1]]
    for k in range(2, 5):
        o = c.plan(float(k), [far], {f"r{i + 1}": seen(s) for i, s in enumerate(spots)}, spare=5)
        if not o.dispatch:
            break
        c.joined(o.dispatch[0][0], f"r{k}")
        spots.append(o.dispatch[0][1])
    views = {f"r{i + 1}": seen(s) for i, s in enumerate(spots)}
    home = Worker("d1", at(5), 15.0, at(5))
    sent: list[str] = []
    for k in range(40):
        gone = c.plan(100.0 + k, [home], views, spare=0).home
        for rid in gone:
            views.pop(rid)  # home and revoked before the next plan: one goes at a time
        sent += gone
    assert sent == [f"r{i}" for i in range(len(spots), 0, -1)]  # the far end first


def test_one_relay_crosses_the_levels_at_a_time() -> None:
    """A relay flying home on its transit level passed 1.4 m over one
    climbing from the ground. A relay no longer needed waits on its spot while another
    comes home (heard or not: world 107's lost its link on the way), then goes."""
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0)
    far = Worker("d1", at(60), 15.0, at(80))
    out = c.plan(0.0, [far], {}, spare=5)
    c.joined(out.dispatch[0][0], "r1")
    spot = out.dispatch[0][1]
    home = Worker("d1", at(5), 15.0, at(5))
    homing = {"r1": seen(spot), "r9": seen(at(20, 90), alt=27.0, fresh=False)}  # r9: sent home, out of reach
    assert not any(c.plan(10.0 + k, [home], homing, spare=0).home for k in range(10))
    homing["r9"] = seen(at(3, 90), alt=0.0)  # landed (and about to be revoked)
    assert c.plan(30.0, [home], homing, spare=0).home == ["r1"]


@settings(max_examples=150, deadline=None)
@given(goal_m=st.floats(40.0, 160.0), bearing=st.floats(0.0, 360.0), spare=st.integers(0, 3),
       home_at_m=st.floats(0.0, 80.0), home_bearing=st.floats(0.0, 360.0), home_alt=st.floats(1.5, 50.0),
       idle=st.booleans(), later_s=st.floats(0.0, 3 * STRETCH_AFTER_S))
def test_while_a_relay_comes_home_no_other_crosses_the_levels(
        goal_m: float, bearing: float, spare: int, home_at_m: float, home_bearing: float, home_alt: float,
        idle: bool, later_s: float) -> None:
    """Relays cross the levels one at a time (ADR 0006): while one flies home, heard or
    not, a plan sends none up or down, whatever else it wants — no relay dispatched,
    none sent home, none moved (out to a stretched spot, or an idle one to a slot: a
    relay climbing to its lane to move passed 1.1 m under one flying home on a lower
    lane, in a world where two workers share a way)."""
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0, holds=56.0)
    out = c.plan(0.0, [Worker("d1", at(5, bearing), 15.0, at(60, bearing))], {}, spare=1)
    (key, spot, _, _), = out.dispatch
    c.joined(key, "r1")
    views = {"r1": seen(spot)}
    if idle:
        c.idle.append("r2")
        views["r2"] = seen(at(10, bearing + 90), alt=DUTY)
    views["r9"] = seen(at(home_at_m, home_bearing), alt=home_alt, fresh=home_alt < 30)  # sent home, in the air
    w = Worker("d1", at(5, bearing), 15.0, at(goal_m, bearing))
    for t in (1.0, 1.0 + later_s, 1.0 + STRETCH_AFTER_S + later_s):
        plan = c.plan(t, [w], views, spare=spare)
        assert (plan.dispatch, plan.home, plan.moves) == ([], [], []), (t, plan)


def test_a_relay_unheard_on_its_way_to_its_spot_still_crosses_the_levels() -> None:
    """A relay lost its link as it climbed out to its spot, and another was sent home
    across its level, 4.6 m from it (a shared-way world). Unheard, it may be anywhere on
    its way: while it was last seen off its spot, no other relay goes home."""
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0)
    w1, w2 = Worker("d1", at(60), 15.0, at(80)), Worker("d2", at(60, 180), 15.0, at(80, 180))
    views: dict[str, Seen] = {}
    for k, rid in enumerate(("r1", "r2")):
        (key, spot, _, _), = c.plan(float(k), [w1, w2], views, spare=5).dispatch
        c.joined(key, rid)
        views[rid] = seen(spot)
    r2_spot = views["r2"].at
    done = Worker("d1", at(5), 15.0, at(5))
    views["r2"] = seen(r2_spot, alt=40.0, fresh=False)  # last heard on its way down to its spot
    assert not any(c.plan(10.0 + k, [done, w2], views, spare=0).home for k in range(5))
    views["r2"] = seen(r2_spot)  # heard again, on its spot
    assert c.plan(20.0, [done, w2], views, spare=0).home == ["r1"]


def test_a_worker_landed_beyond_the_laptops_hop_keeps_no_relay() -> None:
    """A worker landed at its home 35 m from the laptop, beyond the
    hop (30 m), and its relay stayed on duty until the time limit."""
    c = Chains(DUTY)
    c.reach = Reach(lo=31.0, hi=32.0)
    out = c.plan(0.0, [Worker("d1", at(20), 15.0, at(60))], {}, spare=3)
    c.joined(out.dispatch[0][0], "r1")
    views = {"r1": seen(out.dispatch[0][1])}
    landed = Worker("d1", at(35), 0.0, None)
    sent = [rid for k in range(10) for rid in c.plan(10.0 + k, [landed], views, spare=2).home]
    assert sent == ["r1"]


def test_a_relay_assigned_and_still_on_the_ground_is_given_up_and_its_slot_asked_for_again() -> None:
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0)
    w = Worker("d1", at(10), 15.0, at(150))
    (key, spot, _, _), = c.plan(0.0, [w], {}, spare=5).dispatch
    c.joined(key, "r1")
    assert c.plan(LAUNCH_TIMEOUT_S - 1, [w], {"r1": seen(at(5, 90), alt=0.0)}, spare=5).failed == []
    out = c.plan(LAUNCH_TIMEOUT_S + 1, [w], {"r1": seen(at(5, 90), alt=0.0)}, spare=5)
    assert out.failed == ["r1"] and out.dispatch == [(key, spot, 0.0, None)]  # its slot, asked for again in place
    assert c.plan(LAUNCH_TIMEOUT_S + 2, [w], {}, spare=5).dispatch == []  # once
    c.joined(key, "r2")
    assert "r2" in c.relays() and "r1" not in c.relays()


def test_a_held_drone_is_not_held_over_a_drone_that_may_take_off() -> None:
    c = Chains(DUTY)
    c.reach = Reach(lo=40.0, hi=41.0)
    w = Worker("d1", at(0.0), 15.0, at(300))
    parked = at(30)
    c.plan(0.0, [w], {}, spare=0, others=[(parked, 0.0)])
    edge = c.allowed("d1", w.at, w.alt, w.goal)  # type: ignore[arg-type]
    assert dist(edge, parked) >= 6.0 and dist(edge, (0, 0)) > 10
    assert flat(40.0 * MARGIN, 15.0) >= dist(edge, (0, 0))


def test_no_relay_takes_off_while_a_served_drone_flies_over_the_drones_on_the_ground() -> None:
    """A worker passing over the spares' row held 3.1 m from a relay
    climbing through its level. The relay is sent once the worker is 6 m clear."""
    spares = [(at(20, 90), 0.0), (at(27, 90), 0.0)]
    for across, sent in ((3.0, False), (5.5, False), (6.5, True)):
        c = Chains(DUTY)
        c.reach = Reach(lo=50.0, hi=51.0)
        over = Worker("d1", (across, 20.0), 15.0, at(300))  # beside the first spare, on its way out
        out = c.plan(0.0, [over], {}, spare=2, others=spares)
        assert (out.dispatch != []) is sent, (across, out)


def test_no_relay_takes_off_where_a_served_drone_is_let_go_over_the_drones_on_the_ground() -> None:
    """A relay was sent from a spot 12 m from a worker that was let
    go on at the same moment; it stopped 4.9 m from the relay climbing through its level.
    The launch waits while a worker's way to where it may go passes over a spare."""
    spare = [(at(20, 90), 0.0)]
    for where, goal, sent in (((-15.0, 20.0), (300.0, 20.0), False), ((10.0, 20.0), (300.0, 20.0), True),
                              ((-15.0, 20.0), (-300.0, 20.0), True)):
        c = Chains(DUTY)
        c.reach = Reach(lo=50.0, hi=51.0)
        out = c.plan(0.0, [Worker("d1", where, 15.0, goal)], {}, spare=1, others=spare)
        assert (out.dispatch != []) is sent, (where, goal, out)


def test_no_relay_takes_off_on_the_way_home_of_a_served_drone_returning() -> None:
    """A worker's lost-link failsafe flew it home (its goto still the
    script's, far out) and a relay took off on its way, 4.2 m from it. A returning
    drone's way is home: the launch waits while that passes over a spare."""
    spare = [((20.0, 14.0), 0.0)]
    for home, sent in ((None, True), ((0.0, 0.0), False), ((0.0, 60.0), True)):
        c = Chains(DUTY)
        c.reach = Reach(lo=50.0, hi=51.0)
        out = c.plan(0.0, [Worker("d1", (40.0, 28.0), 15.0, (300.0, 200.0), home)], {}, spare=1, others=spare)
        assert (out.dispatch != []) is sent, (home, out)


def test_the_probe_waits_too_while_a_worker_is_over_a_spare() -> None:
    c = Chains(DUTY, first_trial=60.0)
    spare = (at(20, 90), 0.0)
    assert c.plan(0.0, [Worker("d1", (2.0, 20.0), 15.0, at(200))], {}, spare=1, others=[spare]).dispatch == []
    out = c.plan(1.0, [Worker("d1", (12.0, 20.0), 15.0, at(200))], {}, spare=1, others=[spare])
    assert [d[0] for d in out.dispatch] == [PROBE]


def test_a_worker_on_its_way_down_home_is_let_go_at_the_level_it_flies() -> None:
    """A worker's goto home (at field level) is flown at the worker's
    level until its last leg, but the leash judged the way at the goal's: 21 m below the
    relays, nothing of it was covered and the worker was held where it was until the
    time limit. Judged at 15 m, the chain covers the way home."""
    from types import SimpleNamespace

    from dronefleet.mission.script.position import Position
    from dronefleet.mission.script.relaying import Frame, Relays

    field, field_alt = Position(40.6335, -8.6608, 8.0), 8.0
    frame = Frame(field)
    c = Chains(DUTY)
    c.reach = Reach(lo=27.5, hi=28.75)
    c.covered["d1"] = [((0.0, 0.0), 0.0), ((13.7, -9.6), DUTY), ((38.3, -20.0), DUTY)]
    out_there = frame.world((55.2, -16.0))
    worker = SimpleNamespace(id="d1", home=field, position=Position(out_there.lat, out_there.lon, field_alt + 15.0))
    relays = Relays()
    relays._chains, relays._frame, relays._served = c, frame, {"d1": worker}
    verdict = relays.leash("d1", field.lat, field.lon, field_alt)  # home, on the ground
    let_go = (0.0, 0.0) if verdict is None else frame.local(Position(verdict[0], verdict[1]))  # None: all the way
    assert dist(let_go, (55.2, -16.0)) > 10.0, verdict


def test_a_relay_takes_off_from_a_spare_whose_column_no_flying_drone_is_near() -> None:
    """Workers that took off among the spares (a cluster a spawn gap apart): while one
    flies 5 m beside a spare, a relay is sent from another whose column is clear; with
    no spare's spot known, no relay goes until every drone on the ground is clear."""
    spares = [(0.0, 0.0), (0.0, 5.0), (5.0, 0.0), (20.0, 20.0)]
    worker = Worker("d1", (5.0, 5.0), 15.0, at(200))  # 5 m from three of them
    ground = [(p, 0.0) for p in spares]
    out = Chains(DUTY, first_trial=60.0).plan(0.0, [worker], {}, spare=4, others=ground, spares=spares)
    (key, _, _, site), = out.dispatch
    assert key == PROBE and site == (20.0, 20.0)
    assert Chains(DUTY, first_trial=60.0).plan(0.0, [worker], {}, spare=4, others=ground).dispatch == []
    # every spare within reach of a flying drone's column: none goes
    crowded = Worker("d1", (2.5, 2.5), 15.0, at(200))
    near = [(0.0, 0.0), (0.0, 5.0), (5.0, 0.0)]
    out = Chains(DUTY, first_trial=60.0).plan(0.0, [crowded], {}, spare=3, others=[(p, 0.0) for p in near], spares=near)
    assert out.dispatch == []


@settings(max_examples=150, deadline=None, database=None)
@given(out_m=st.floats(15.0, 120.0), bearing=st.floats(0.0, 360.0), home_m=st.floats(0.0, 12.0),
       home_bearing=st.floats(0.0, 360.0),
       spares=st.lists(st.tuples(st.floats(-40.0, 40.0), st.floats(-40.0, 40.0)), min_size=1, max_size=8))
def test_no_relay_climbs_under_the_way_of_a_drone_in_the_air_whatever_level_it_flies_to(
        out_m: float, bearing: float, home_m: float, home_bearing: float, spares: list[tuple[float, float]]) -> None:
    """A worker flying down to its home (its goto's level is 0 m) is in the air all the
    way there: while another worker's chain sends a relay, that relay takes off only from
    a spare the parked clearance across from every way flown (judged by its level alone, the
    way down was left out, and a relay climbed 3.7 m from a worker landing beside it)."""
    home = at(home_m, home_bearing)
    down = Worker("d1", at(out_m, bearing), 0.0, home, airborne=True)
    far = Worker("d2", at(30.0, bearing + 180.0), 15.0, at(250.0, bearing + 180.0))
    c = Chains(DUTY)
    c.reach = Reach(lo=50.0, hi=51.0)
    out = c.plan(0.0, [down, far], {}, spare=len(spares), others=[(p, 0.0) for p in spares], spares=spares)
    assert any(a == down.at for a, _ in c.legs), c.legs
    for _, _, _, site in out.dispatch:
        assert site is not None
        for a, b in c.legs:
            assert segment_distance((*a, 0.0), (*b, 0.0), (*site, 0.0), (*site, 0.0)) >= Separation().parked_m, (site, a, b)
