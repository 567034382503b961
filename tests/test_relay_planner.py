"""The relay planner as pure logic (issue 15): geometry in, relay points and orders out."""

from __future__ import annotations

import math

import pytest

from relay.planner import Drone, Params, Relay, cover, dist, duty_altitude, path_quality, plan, reach

P = Params()  # the default radio: good to 60 m, lost at 100 m; min_quality 0.6 → 76 m, 64.6 m with the margin


def at(metres: float, bearing_deg: float) -> tuple[float, float]:
    b = math.radians(bearing_deg)
    return metres * math.cos(b), metres * math.sin(b)


def test_a_drone_in_good_range_needs_no_relay() -> None:
    result = plan([Drone("d1", at(50, 0))], [], P)
    assert result.points == [] and result.dispatch == [] and result.home == []


def test_a_far_drone_gets_a_chain_whose_every_hop_is_in_reach() -> None:
    result = plan([Drone("d1", at(180, 30))], [], P)
    hop = reach(P)
    assert len(result.points) == 2  # 180 m in hops of at most 64.6 m
    chain = [(0.0, 0.0), *sorted(result.points, key=lambda p: dist(p, (0, 0))), at(180, 30)]
    assert all(dist(a, b) <= hop + 1e-6 for a, b in zip(chain, chain[1:], strict=False)), chain
    assert [alt for _, alt in result.dispatch] == [10.0, 5.0]  # script 5.9: base+diff, then base


def test_one_relay_serves_two_drones_the_one_chain_per_drone_baseline_would_give_two() -> None:
    drones = [Drone("d1", at(110, 0)), Drone("d2", at(110, 60))]
    result = plan(drones, [], P)
    assert len(result.points) == 1, result.points
    assert result.served == {"0": ["d1", "d2"]}
    (relay,) = result.points
    assert all(dist(relay, d.at) <= reach(P) for d in drones) and dist(relay, (0, 0)) <= reach(P)


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
    """At 70 m the model predicts 0.75 (> 0.6); the drone measures 0.3: the radio is
    worse here, so the planner trusts the model less and a relay is placed."""
    d = Drone("d1", at(70, 0), quality=0.3)
    first = plan([d], [], P)
    assert first.scale < 1.0
    scale, rounds = first.scale, 0
    result = first
    while not result.points and rounds < 20:
        result = plan([d], [], P, scale)
        scale, rounds = result.scale, rounds + 1
    assert result.points and rounds < 20, (scale, rounds)
    assert plan([Drone("d1", at(30, 0), quality=1.0)], [], P, scale).scale > scale  # good again: trust grows back


def test_relays_keep_their_target_unless_it_moves_more_than_step() -> None:
    d = Drone("d1", at(120, 0))
    first = plan([d], [], P)
    (point,) = first.points
    relay = Relay("r1", at=point, target=point, alt=10.0)
    assert plan([Drone("d1", at(122, 0))], [relay], P).moves == []  # the point moved < 4 m
    moved = plan([Drone("d1", at(125, 10))], [relay], P)
    assert [m.relay for m in moved.moves] == ["r1"] and moved.dispatch == []


def test_a_relay_no_longer_needed_goes_home_and_is_called_back_before_a_new_one() -> None:
    relay = Relay("r1", at=at(50, 0), target=at(50, 0), alt=10.0)
    back = plan([Drone("d1", at(40, 0))], [relay], P)
    assert back.home == ["r1"] and back.points == []
    returning = Relay("r1", at=at(20, 0), target=(0.0, 0.0), alt=10.0, serving=False)
    again = plan([Drone("d1", at(120, 0))], [returning], P)
    assert [m.relay for m in again.moves] == ["r1"] and again.dispatch == []


def test_relay_points_keep_the_separation_from_the_drones_they_serve() -> None:
    params = Params(min_separation=20.0)
    drones = [Drone("d1", at(70, 0)), Drone("d2", at(70, 10))]
    for pt in plan(drones, [], params).points:
        assert all(dist(pt, d.at) >= 20.0 - 1e-6 for d in drones)


def test_cover_connects_everyone_with_bounded_hops() -> None:
    spots = {f"d{i}": at(90 + 25 * i, 47 * i) for i in range(6)}
    points, _ = cover(spots, 60.0)
    for d, spot in spots.items():
        assert path_quality(spot, points + [s for k, s in spots.items() if k != d], Params(good_m=60.0, lost_m=100.0, margin=1.0), 1.0) > 0.99, d


@pytest.mark.parametrize(("index", "alt"), [(0, 10.0), (1, 5.0), (2, 10.0)])
def test_duty_altitudes_alternate(index: int, alt: float) -> None:
    assert duty_altitude(index, P) == alt


def test_scripts_plan_in_metres_around_the_ground_and_get_positions_back() -> None:
    """mission/relaying.py: positions to the planner's plane and back (sim.projection)."""
    from mission import units
    from mission.geo import Position
    from mission.relaying import Frame, Relays

    frame = Frame(Position(40.634125, -8.660336))
    spot = frame.world((-129.0, 9.0))
    assert Position(40.634125, -8.660336).distance(spot) == pytest.approx(math.hypot(129.0, 9.0), rel=1e-3)
    assert frame.local(spot) == pytest.approx((-129.0, 9.0))
    params = Relays().params(min_quality=0.5, step=4 * units.m, base_alt=5 * units.m)
    assert (params.min_quality, params.step, params.base_alt) == (0.5, 4.0, 5.0)
