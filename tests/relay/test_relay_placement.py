"""The relay planner as pure logic (issue 15): geometry in, relay points and orders out."""

from __future__ import annotations

import math
import random

import pytest

from dronefleet.relay.distance import keep_clear
from dronefleet.relay.placement import Drone, Params, Relay, dist, duty_altitude, link_quality, path_quality, plan

P = Params()  # the default radio: good to 60 m, lost at 100 m; min_quality 0.6 → 76 m, 64.6 m with the margin


def at(metres: float, bearing_deg: float) -> tuple[float, float]:
    b = math.radians(bearing_deg)
    return metres * math.cos(b), metres * math.sin(b)


def test_a_drone_in_good_range_needs_no_relay() -> None:
    result = plan([Drone("d1", at(50, 0))], [], P)
    assert result.points == [] and result.dispatch == [] and result.home == []


def test_a_far_drone_gets_a_chain_the_fewest_hop_routing_keeps_in_good_quality() -> None:
    result = plan([Drone("d1", at(180, 30))], [], P)
    assert len(result.points) == 2, result.points  # 180 m: three hops of at most 76 m (quality 0.6)
    assert path_quality(at(180, 30), result.points, P, 1.0) >= P.min_quality
    assert [alt for _, alt in result.dispatch] == [10.0, 5.0]  # script 5.9: base+diff, then base


def test_a_relay_short_cut_by_a_lossy_link_does_not_count() -> None:
    """The mesh routes on hop count: at 82 m the drone's own lossy link to the ground
    (quality 0.45) is one hop, so a relay halfway adds nothing while that link holds;
    past 86 m (65 % of the packets lost) such a link rarely stays up."""
    assert path_quality(at(82, 0), [at(41, 0)], P, 1.0) == pytest.approx(0.45)
    assert path_quality(at(90, 0), [at(45, 0)], P, 1.0) == pytest.approx(1.0)
    assert path_quality(at(123, 0), [at(41, 0), at(82, 0)], P, 1.0) == pytest.approx(0.45)  # ground-82 m is one lossy hop
    assert path_quality(at(130, 0), [at(65, 0)], P, 1.0) == pytest.approx(0.875 ** 2)


def test_one_relay_serves_two_drones_the_one_chain_per_drone_baseline_would_give_two() -> None:
    drones = [Drone("d1", at(110, 0)), Drone("d2", at(110, 60))]
    result = plan(drones, [], P)
    assert len(result.points) == 1, result.points
    for d in drones:
        assert path_quality(d.at, [*result.points, *(o.at for o in drones if o is not d)], P, 1.0) >= P.min_quality


def test_a_drone_near_a_connected_one_needs_no_relay_of_its_own() -> None:
    """The mesh routes through mission drones: d2 reaches the ground through d1."""
    result = plan([Drone("d1", at(55, 0)), Drone("d2", at(110, 0))], [], P)
    assert result.points == []


def test_where_the_drone_is_going_counts_not_only_where_it_is() -> None:
    going = Drone("d1", at(50, 0), velocity=(8.0, 0.0), goal=at(200, 0))
    assert plan([going], [], P).points  # 130 m in 10 s: a relay is dispatched now
    coming_back = Drone("d1", at(50, 0), velocity=(-8.0, 0.0), goal=(0.0, 0.0))
    assert plan([coming_back], [], P).points == []


def test_measured_quality_worse_than_the_model_shrinks_the_hops() -> None:
    """At 70 m the model predicts 0.75; the drone measures 0.3: the radio is worse
    here, so the planner shrinks the model's range until it predicts what is measured.
    A drone at 76 m, fine for the unscaled model (0.6), then gets a relay."""
    d = Drone("d1", at(70, 0), quality=0.3)
    assert plan([Drone("d1", at(76, 0))], [], P).points == []
    scale, steady, rounds = 1.0, 0, 0
    while rounds < 400:
        result = plan([d], [], P, scale, steady=steady)
        if result.scale == scale and result.steady >= 12:
            break
        scale, steady, rounds = result.scale, result.steady, rounds + 1
    assert 0.4 <= scale < 0.85 and rounds < 400, (scale, rounds)
    assert path_quality(d.at, [], P, scale) <= 0.4
    assert plan([Drone("d1", at(76, 0))], [], P, scale).points
    assert plan([Drone("d1", at(30, 0), quality=1.0)], [], P, scale, steady=11).scale > scale  # good again: trust grows back
    moving = Drone("d1", at(70, 0), velocity=(3.0, 0.0), quality=0.3)
    assert plan([moving], [], P, 1.0, steady=50).scale == 1.0  # its window is not this geometry's


def test_relays_keep_their_target_unless_it_moves_more_than_step() -> None:
    d = Drone("d1", at(120, 0))
    first = plan([d], [], P)
    (point,) = first.points
    relay = Relay("r1", at=point, target=point, alt=10.0)
    assert plan([Drone("d1", at(125, 10))], [relay], P).moves == []  # still good where it is
    moved = plan([Drone("d1", at(135, 20))], [relay], P)
    assert [m.relay for m in moved.moves] == ["r1"] and moved.dispatch == []


def test_a_relay_no_longer_needed_goes_home_and_is_called_back_before_a_new_one() -> None:
    relay = Relay("r1", at=at(50, 0), target=at(50, 0), alt=10.0)
    back = plan([Drone("d1", at(40, 0))], [relay], P)
    assert back.home == ["r1"] and back.points == []
    returning = Relay("r1", at=at(20, 0), target=(0.0, 0.0), alt=10.0, serving=False)
    again = plan([Drone("d1", at(120, 0))], [returning], P)
    assert [m.relay for m in again.moves] == ["r1"] and again.dispatch == []


def test_relay_points_keep_the_separation_from_the_drones_they_serve() -> None:
    params = Params(min_separation_m=20.0)
    drones = [Drone("d1", at(70, 0)), Drone("d2", at(70, 10))]
    for pt in plan(drones, [], params).points:
        assert all(dist(pt, d.at) >= 20.0 - 1e-6 for d in drones)


def test_drones_scattered_around_all_end_in_good_quality() -> None:
    drones = [Drone(f"d{i}", at(90 + 25 * i, 60 * i)) for i in range(3)]
    points = plan(drones, [], P).points
    assert len(points) <= 3, points
    for d in drones:
        assert path_quality(d.at, points + [o.at for o in drones if o.id != d.id], P, 1.0) >= P.min_quality, d


@pytest.mark.parametrize(("index", "alt"), [(0, 10.0), (1, 5.0), (2, 10.0)])
def test_duty_altitudes_alternate(index: int, alt: float) -> None:
    assert duty_altitude(index, P) == alt


def test_scripts_plan_in_metres_around_the_ground_and_get_positions_back() -> None:
    """mission/relaying.py: positions to the planner's plane and back (sim.projection)."""
    from dronefleet.mission.script import units
    from dronefleet.mission.script.position import Position
    from dronefleet.mission.script.relaying import Frame, Relays

    frame = Frame(Position(40.634125, -8.660336))
    spot = frame.world((-129.0, 9.0))
    assert Position(40.634125, -8.660336).distance(spot) == pytest.approx(math.hypot(129.0, 9.0), rel=1e-3)
    assert frame.local(spot) == pytest.approx((-129.0, 9.0))
    params = Relays().params(min_quality=0.5, step=4 * units.m, base_alt=5 * units.m)
    assert (params.min_quality, params.step_m, params.base_alt_m) == (0.5, 4.0, 5.0)


@pytest.mark.parametrize(("spot", "alt", "others"), [
    ((10.0, 0.0), 10.0, [((10.0, 0.0), 10.0)]),  # right on another drone
    ((10.0, 0.0), 10.0, [((10.0, 0.0), 5.0)]),  # right above one, 5 m: not more than min_separation
    ((10.0, 2.0), 10.0, [((10.0, 0.0), 10.0), ((10.0, 5.0), 10.0), ((14.0, 2.0), 10.0)]),  # crowded
    ((0.0, 0.0), 5.0, [((0.0, 0.0), 5.0)]),  # at the ground station itself
])
def test_the_distance_baselines_targets_keep_the_separation(spot: tuple[float, float], alt: float,
                                                            others: list[tuple[tuple[float, float], float]]) -> None:
    """Script 5.12 has no separation; mode="distance" moves its target just clear (3-D)."""
    clear = keep_clear(spot, alt, others, 5.0)
    for p, a in others:
        assert math.hypot(dist(p, clear), a - alt) >= 5.0, (clear, p)
    assert dist(clear, spot) < 15.0  # moved aside, not sent away


def test_a_distance_target_already_clear_stays() -> None:
    assert keep_clear((10.0, 0.0), 10.0, [((30.0, 0.0), 10.0), ((10.0, 0.0), 16.5)], 5.0) == (10.0, 0.0)


def test_duty_altitudes_rise_clear_of_the_altitude_the_drones_fly_at() -> None:
    """A drone flying back toward the ground passes where its relays hover: at 10 m
    (script 5.9's first level) a relay met it 0.1 m away on real packets."""
    result = plan([Drone("d1", at(180, 30), alt=10.0)], [], P)
    alts = [alt for _, alt in result.dispatch]
    assert len(alts) == 2 and alts[0] - alts[1] == P.alt_diff_m, alts  # still alternating
    assert all(abs(alt - 10.0) >= P.min_separation_m for alt in alts), alts
    # a relay on duty whose level a drone climbed to is moved up, where it is
    relay = Relay("r1", at(90, 30), target=at(90, 30), alt=10.0)
    moved = plan([Drone("d1", at(150, 30), alt=12.0)], [relay], P).moves
    assert [m.relay for m in moved] == ["r1"] and abs(moved[0].alt - 12.0) >= P.min_separation_m, moved
    assert duty_altitude(0, P, [30.0]) == 10.0  # drones far above: the thesis's levels


def test_path_quality_is_the_fewest_hop_walk_over_link_quality() -> None:
    """relay.placement.Mesh inlines the link model for speed: on 300 random meshes (radios,
    scales, node counts) it gives exactly what a walk over link_quality gives, so the
    model has one meaning however often it is written."""
    rng = random.Random(32)
    for _ in range(300):
        good = rng.uniform(25, 150)
        p = Params(good_m=good, lost_m=good * rng.uniform(1.3, 2.0))
        scale = rng.uniform(0.5, 1.5)
        nodes = [(rng.uniform(-300, 300), rng.uniform(-300, 300)) for _ in range(rng.randint(0, 8))]
        spot = (rng.uniform(-400, 400), rng.uniform(-400, 400))
        everything = [(0.0, 0.0), *nodes, spot]
        quality, frontier = {0: 1.0}, [0]
        while frontier and len(everything) - 1 not in quality:
            level = {}
            for j, b in enumerate(everything):
                links = [quality[i] * q for i in frontier if j not in quality
                         and (q := link_quality(everything[i], b, p, scale)) is not None]
                if links:
                    level[j] = min(links)
            quality.update(level)
            frontier = list(level)
        assert path_quality(spot, nodes, p, scale) == quality.get(len(everything) - 1, 0.0)
