"""When the relay plugin plans (relay/rounds.py), as properties over random hearings."""

from __future__ import annotations

import itertools

from hypothesis import given
from hypothesis import strategies as st

from dronefleet.relay.rounds import PLAN_EVERY_S, PlanRounds

DRONES = ["drone01", "drone02", "drone03"]
# Who is heard, and how long after the hearing before: every 50 ms to 3 s.
hearings = st.lists(st.tuples(st.sampled_from(DRONES), st.floats(0.05, 3.0)), min_size=1, max_size=300)


def played(heard: list[tuple[str, float]]) -> list[tuple[str, float, bool]]:
    rounds, now, out = PlanRounds(), 0.0, []
    for drone, after_s in heard:
        now += after_s
        out.append((drone, now, rounds.due(drone, now)))
    return out


@given(hearings)
def test_plans_are_never_closer_than_the_period_however_often_drones_speak(heard: list[tuple[str, float]]) -> None:
    plans = [t for _, t, due in played(heard) if due]
    assert all(b - a >= PLAN_EVERY_S for a, b in itertools.pairwise(plans)), plans


@given(hearings)
def test_a_drone_heard_again_a_period_after_the_last_plan_always_plans(heard: list[tuple[str, float]]) -> None:
    """Liveness: one drone that goes on speaking keeps the plans coming (a drone out of
    reach never holds the round open), and nothing plans before anyone is heard twice."""
    last_plan, seen = None, set()
    for drone, t, due in played(heard):
        again = drone in seen
        if again and (last_plan is None or t - last_plan >= PLAN_EVERY_S):
            assert due, (drone, t, last_plan)
        if not again:
            assert not due
        if due:
            last_plan, seen = t, {drone}
        else:
            seen.add(drone)


def test_one_drone_speaking_every_250_ms_plans_once_a_period() -> None:
    """A drone in doubt of the ground speaks four times a second: one plan a period."""
    plans = [t for _, t, due in played([("drone01", 0.25)] * 80) if due]
    assert len(plans) >= 15 and all(0.9 <= b - a <= 1.0 for a, b in itertools.pairwise(plans)), plans
