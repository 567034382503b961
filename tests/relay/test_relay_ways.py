"""Leashed workers keep out of each other's way (relay/ways.py): pure, no I/O."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from dronefleet.relay.rules import Separation
from dronefleet.relay.ways import (
    AIRBORNE_M,
    LAND_RATE_MPS,
    YIELD_LIMIT_S,
    Point3,
    Ways,
    closest_approach,
    descent_clear,
    segment_distance,
)

CLEAR_M = Separation().way_m  # the way clearance at the default 5 m


@pytest.mark.parametrize(("a", "b", "c", "d", "expected"), [
    ((0, 0, 0), (10, 0, 0), (5, -5, 3), (5, 5, 3), 3.0),  # crossing, 3 m apart in height
    ((0, 0, 0), (10, 0, 0), (12, 0, 0), (20, 0, 0), 2.0),  # in line, end to end
    ((0, 0, 0), (10, 0, 0), (3, 4, 0), (3, 4, 0), 4.0),  # a point beside
    ((0, 0, 0), (0, 0, 0), (3, 4, 0), (3, 4, 0), 5.0),  # two points
    ((0, 0, 0), (10, 0, 0), (0, 2, 0), (10, 2, 0), 2.0),  # parallel
    ((0, 0, 0), (1, 0, 0), (1, 0, 0), (0, 0, 1e-5), 0.0),  # nearly parallel, sharing an end
    ((0, 0, 0), (10, 0, 0), (12, 1, 0), (20, 1, 0), math.hypot(2, 1)),  # parallel, apart along
])
def test_segment_distance(a: Point3, b: Point3, c: Point3, d: Point3, expected: float) -> None:
    assert segment_distance(a, b, c, d) == pytest.approx(expected)
    assert segment_distance(c, d, a, b) == pytest.approx(expected)


coordinate = st.floats(-200, 200, allow_nan=False)
point = st.tuples(coordinate, coordinate, st.floats(0, 60, allow_nan=False))


@settings(max_examples=300, deadline=None)
@given(point, point, point, point)
def test_the_closest_approach_in_continuous_time_is_the_least_of_every_moment(
        a0: Point3, a1: Point3, b0: Point3, b1: Point3) -> None:
    """Two drones each flying straight at constant speed over one interval: the closest
    approach is never above the distance at any moment of it (fine samples included, the
    ends too), and some moment comes within a sampling step's travel of it; it is never
    below the least distance between the two ways flown (where they were, at any time)."""
    least = closest_approach(a0, a1, b0, b1)
    steps = 400
    at = [math.dist([p + i / steps * (q - p) for p, q in zip(a0, a1, strict=True)],
                    [p + i / steps * (q - p) for p, q in zip(b0, b1, strict=True)]) for i in range(steps + 1)]
    step_travel = (math.dist(a0, a1) + math.dist(b0, b1)) / steps
    assert least <= min(at) + 1e-6
    assert min(at) <= least + step_travel + 1e-6
    assert least >= segment_distance(a0, a1, b0, b1) - 1e-6


def test_two_drones_crossing_between_two_samples_are_judged_at_their_closest() -> None:
    """Samples 1 s apart show 10 m at each end; half-way they pass 3 m apart in height."""
    assert closest_approach((-5, 0, 15), (5, 0, 15), (0, -5, 18), (0, 5, 18)) == pytest.approx(3.0)
    assert min(math.dist((-5, 0, 15), (0, -5, 18)), math.dist((5, 0, 15), (0, 5, 18))) > 7


speed = st.floats(-12, 12, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(st.tuples(coordinate, coordinate, st.floats(2, 60, allow_nan=False)),
       st.lists(st.tuples(point, st.tuples(speed, speed)), max_size=4))
def test_a_relay_comes_down_only_where_no_drone_below_passes_its_column_meanwhile(
        column: Point3, below: list[tuple[Point3, tuple[float, float]]]) -> None:
    """The invariant of a relay's descent: when it may come down, every drone flying
    below it, flying straight on at its velocity, keeps CLEAR_M across from the column
    at every moment of the descent (judged at LAND_RATE_MPS); when it may not, one of
    them comes within CLEAR_M of it in that time."""
    lasts_s = max(0.0, column[2] - AIRBORNE_M) / LAND_RATE_MPS
    steps = 200

    def nearest(at: Point3, v: tuple[float, float]) -> float:
        return min(math.dist(column[:2], (at[0] + v[0] * lasts_s * i / steps, at[1] + v[1] * lasts_s * i / steps))
                   for i in range(steps + 1))

    under = [(at, v) for at, v in below if AIRBORNE_M < at[2] < column[2]]
    step_m = max((math.hypot(*v) * lasts_s / steps for _, v in under), default=0.0)
    if descent_clear(column, below, CLEAR_M):
        assert all(nearest(at, v) >= CLEAR_M - 1e-6 for at, v in under)
    else:
        assert any(nearest(at, v) < CLEAR_M + step_m for at, v in under)


def test_a_worker_flying_home_under_a_relay_keeps_it_up_until_it_has_passed() -> None:
    """As seen: a relay over its home 45 m up, a worker at 15 m flying home at 5 m/s
    along a way 2.5 m from the column, 130 m out. A snapshot finds it far away; its way
    over the descent does not. Once past and landed, the relay may come down."""
    column = (8.0, 10.0, 45.0)
    assert not descent_clear(column, [((79.8, 109.2, 15.0), (-2.95, -4.05))], CLEAR_M)
    assert descent_clear(column, [((0.0, 0.0, 0.5), (0.0, 0.0))], CLEAR_M)
    assert descent_clear(column, [((79.8, 109.2, 15.0), (2.95, 4.05))], CLEAR_M)  # flying away


def test_a_worker_waits_short_of_another_workers_way_and_goes_on_once_it_has_flown() -> None:
    ways = Ways()
    workers = {"drone01", "drone02"}
    # drone01 sets out east; its way is declared
    end, other = ways.clear("drone01", (0, 0, 15), (0, 100, 15), {"drone02": (50, 50, 15)}, workers, now=0.0)
    assert end == (0, 100, 15) and other is None
    # drone02, hovering 50 m north, wants to fly south across it: it stops short
    end, other = ways.clear("drone02", (50, 50, 15), (-50, 50, 15), {"drone01": (0, 10, 15)}, workers, now=1.0)
    assert other == "drone01"
    assert end[0] > 0 and segment_distance((50, 50, 15), end, (0, 10, 15), (0, 100, 15)) >= CLEAR_M - 0.1
    assert segment_distance((50, 50, 15), end, (0, 10, 15), (0, 100, 15)) < CLEAR_M + 1.0  # as far as it may
    # drone01 has flown past the crossing: what is left of its way no longer crosses
    end, other = ways.clear("drone02", end, (-50, 50, 15), {"drone01": (0, 70, 15)}, workers, now=5.0)
    assert end == (-50, 50, 15) and other is None


def test_a_worker_does_not_fly_over_one_that_has_not_taken_off_but_may_over_one_that_landed() -> None:
    ways = Ways()
    workers = {"drone01", "drone02"}
    end, other = ways.clear("drone01", (0, 0, 15), (0, 40, 15), {"drone02": (0, 10, 0)}, workers, now=0.0)
    assert other == "drone02" and math.dist(end, (0, 10, 15)) >= CLEAR_M - 0.1 and end[1] < 10
    ways.clear("drone02", (0, 10, 15), (0, 10, 15), {"drone01": end}, workers, now=1.0)  # it flies …
    ways.clear("drone01", end, end, {"drone02": (30, 10, 15)}, workers, now=2.0)
    end, other = ways.clear("drone01", end, (0, 40, 15), {"drone02": (0, 10, 0)}, workers, now=3.0)  # … and lands
    assert end == (0, 40, 15) and other is None


def test_relays_hovering_above_the_workers_level_are_not_in_the_way() -> None:
    end, other = Ways().clear("drone01", (0, 0, 15), (0, 100, 15), {"drone05": (0, 50, 21)},
                              {"drone01"}, now=0.0)
    assert end == (0, 100, 15) and other is None


def test_a_worker_does_not_fly_over_a_relay_climbing_through_its_level() -> None:
    """A relay taking off beside a worker's way was 3 m up when the
    worker passed over it, and 3.1 m from it when it climbed through 15 m."""
    ways = Ways()
    end, other = ways.clear("drone01", (0, 0, 15), (0, 40, 15), {"drone05": (2, 20, 3)}, {"drone01"}, now=0.0)
    assert other == "drone05" and end[1] < 20 and segment_distance((0, 0, 15), end, (2, 20, 0), (2, 20, 25)) >= CLEAR_M - 0.1
    # sent, still on the ground: it takes off next; not sent: a drone on the ground
    end, other = Ways().clear("drone01", (0, 0, 15), (0, 40, 15), {"drone05": (2, 20, 0)}, {"drone01"}, 0.0, {"drone05"})
    assert other == "drone05" and end[1] < 20
    assert Ways().clear("drone01", (0, 0, 15), (0, 40, 15), {"drone05": (2, 20, 0)}, {"drone01"}, 0.0) == ((0, 40, 15), None)
    # once it is above the worker's level (its duty), the worker passes under it
    end, other = ways.clear("drone01", end, (0, 40, 15), {"drone05": (2, 20, 21)}, {"drone01"}, now=5.0)
    assert end == (0, 40, 15) and other is None


def test_two_workers_each_waiting_on_the_others_way_do_not_wait_for_ever() -> None:
    ways = Ways()
    workers = {"drone01", "drone02"}
    # drone01 has declared its way east; drone02, hovering 7 m beside it, wants across
    ways.legs["drone01"] = ((0, 0, 15), (100, 0, 15))
    end, other = ways.clear("drone02", (50, 7, 15), (50, -20, 15), {"drone01": (0, 0, 15)}, workers, now=0.0)
    assert other == "drone01" and end[1] > 6.9
    # drone01 is blocked by where drone02 waits (7 m from its way), and drone02 waits on
    # drone01: drone01, first by name, goes, keeping AROUND_M
    end, other = ways.clear("drone01", (0, 0, 15), (100, 0, 15), {"drone02": (50, 7, 15)}, workers, now=1.0)
    assert end == (100, 0, 15) and other == "drone02"
    # drone02 still waits for drone01 to pass
    end, other = ways.clear("drone02", (50, 7, 15), (50, -20, 15), {"drone01": (10, 0, 15)}, workers, now=2.0)
    assert other == "drone01" and end[1] > 6.9
    end, other = ways.clear("drone02", (50, 7, 15), (50, -20, 15), {"drone01": (90, 0, 15)}, workers, now=9.0)
    assert end == (50, -20, 15) and other is None


def test_two_workers_kept_waiting_as_long_do_not_set_out_across_each_other() -> None:
    """Two workers waiting on each other for 20 s went in the same
    second, each keeping clear of where the other was, and crossed 2.6 m apart. The one
    that sets out first declares its way; the other keeps CLEAR_M from it."""
    ways = Ways()
    workers = {"drone01", "drone02"}
    ways.waiting = {"drone01": 0.0, "drone02": 0.0}
    one, two = (-15.1, -9.0, 15.0), (-24.1, -10.6, 15.0)
    end_one, _ = ways.clear("drone01", one, (-15.0, -40.0, 15.0), {"drone02": two}, workers, now=YIELD_LIMIT_S)
    assert end_one == (-15.0, -40.0, 15.0)
    end_two, other = ways.clear("drone02", two, (0.0, -30.0, 15.0), {"drone01": one}, workers, now=YIELD_LIMIT_S)
    assert other == "drone01"
    assert segment_distance(two, end_two, one, end_one) >= CLEAR_M - 0.1


def test_a_worker_kept_waiting_goes_but_never_through_where_another_drone_is() -> None:
    ways = Ways()
    workers = {"drone01", "drone02"}
    ways.legs["drone02"] = ((50, 20, 15), (50, -20, 15))
    others = {"drone02": (50, 20, 15)}
    end, other = ways.clear("drone01", (0, 0, 15), (100, 0, 15), others, workers, now=0.0)
    assert other == "drone02" and end[0] < 50
    end, other = ways.clear("drone01", (0, 0, 15), (100, 0, 15), others, workers, now=YIELD_LIMIT_S)
    assert end == (100, 0, 15) and other == "drone02"  # past its way, 20 m from where it is
    end, other = ways.clear("drone01", (0, 0, 15), (100, 0, 15), {"drone02": (50, 3, 15)}, workers,
                            now=2 * YIELD_LIMIT_S)
    assert other == "drone02" and end[0] < 50  # … never through it


def test_workers_that_took_off_side_by_side_may_part_but_not_close_in() -> None:
    workers = {"drone01", "drone02"}
    end, other = Ways().clear("drone01", (0, 0, 15), (0, -100, 15), {"drone02": (0, 6, 15)}, workers, now=0.0)
    assert end == (0, -100, 15) and other is None
    end, other = Ways().clear("drone01", (0, 0, 15), (100, 30, 15), {"drone02": (0, 6, 15)}, workers, now=0.0)
    assert other == "drone02" and math.dist(end, (0, 0, 15)) < 1.0


def test_two_workers_each_in_the_others_way_the_later_steps_aside() -> None:
    """Two workers that took off 5.5 m apart, each wanting to fly
    through where the other waits, waited for ever."""
    ways = Ways()
    workers = {"drone01", "drone02"}
    one, two = (0.0, 0.0, 15.0), (0.0, 5.5, 15.0)
    assert ways.clear("drone01", one, (0, 100, 15), {"drone02": two}, workers, now=0.0) == (one, "drone02")
    assert ways.clear("drone02", two, (0, -100, 15), {"drone01": one}, workers, now=0.0)[1] == "drone01"
    end, other = ways.clear("drone02", two, (0, -100, 15), {"drone01": one}, workers, now=YIELD_LIMIT_S)
    assert other == "drone01" and abs(abs(end[0]) - (CLEAR_M + 1)) < 0.01 and end[1:] == two[1:]  # across drone01's way
    end, other = ways.clear("drone01", one, (0, 100, 15), {"drone02": end}, workers, now=YIELD_LIMIT_S + 5)
    assert end == (0, 100, 15) and other is None


# ---- properties over random crowds (ADR 0006: separation and liveness) ------------------

SPEED_M_S = 5.0
TICK_S = 0.5


def _fly_crowd(spots: list[Point3], goals: list[Point3], ticks: int) -> tuple[list[Point3], float]:
    """Workers that took off at `spots` fly toward `goals` as the ways let them (each
    evaluated in turn every tick, the leg flown at SPEED_M_S) and land there; where they
    ended, and by how much two flying drones came closer than 5 m or than they took off
    (negative: they did)."""
    ways, names = Ways(), [f"drone{i + 1:02d}" for i in range(len(spots))]
    at = dict(zip(names, spots, strict=True))
    goal = dict(zip(names, goals, strict=True))
    least = math.inf
    start = {(a, b): math.dist(at[a], at[b]) for a in names for b in names if a < b}
    for tick in range(ticks):
        for d in names:
            if math.dist(at[d], goal[d]) < 0.5:
                at[d] = (*goal[d][:2], 0.0)  # landed there: out of the others' way
            if at[d][2] == 0.0:
                continue
            end, _ = ways.clear(d, at[d], goal[d], {o: p for o, p in at.items() if o != d}, set(names), tick * TICK_S)
            step = min(SPEED_M_S * TICK_S, math.dist(at[d], end))
            if step > 0:
                u = [(e - a) / math.dist(at[d], end) for a, e in zip(at[d], end, strict=True)]
                at[d] = (at[d][0] + u[0] * step, at[d][1] + u[1] * step, at[d][2] + u[2] * step)
        for (a, b), first in start.items():
            if at[a][2] > 0 and at[b][2] > 0:
                least = min(least, math.dist(at[a], at[b]) - min(first, 5.0))
    return [at[d] for d in names], least


@settings(max_examples=200, deadline=None)
@given(n=st.integers(2, 3), spacing=st.floats(5.0, 7.0), rows=st.integers(1, 2), turn=st.floats(0, 360),
       bearings=st.lists(st.floats(0, 360), min_size=4, max_size=4), out=st.floats(60, 200))
def test_workers_that_took_off_side_by_side_all_get_out_and_never_close_in(
        n: int, spacing: float, rows: int, turn: float, bearings: list[float], out: float) -> None:
    """Two or three workers standing a spawn gap apart in a row or a small grid, each
    sent to a random bearing: every one reaches its goal (no ring waits for ever) and no
    two come closer than 5 m, or than they took off, whichever is less (1,360 random
    cases: none failed, the least margin 0.0 m; with a centimetre of slack for those
    already near, two waiting side by side crept 0.31 m closer). Four do not hold yet:
    of 615 random cases, two stayed short of their goals and one pair closed 0.22 m
    under (two workers kept waiting go at once, each clear of where the other was;
    ADR 0006)."""
    t = math.radians(turn)
    spots = []
    for i in range(n):
        r, c = divmod(i, math.ceil(n / rows))
        x, y = r * spacing, c * spacing
        spots.append((x * math.cos(t) - y * math.sin(t), x * math.sin(t) + y * math.cos(t), 15.0))
    goals = [(out * math.cos(math.radians(b)), out * math.sin(math.radians(b)), 15.0) for b in bearings[:n]]
    assume(all(math.dist(g, h) > 2 * CLEAR_M for i, g in enumerate(goals) for h in goals[i + 1:]))
    ends, least = _fly_crowd(spots, goals, ticks=int(3 * (out + 100) / (SPEED_M_S * TICK_S)))
    assert least > -0.1  # each moves on where the others were a tick before: a few centimetres
    assert all(math.dist(e[:2], g[:2]) < 0.5 for e, g in zip(ends, goals, strict=True)), list(zip(ends, goals, strict=True))
