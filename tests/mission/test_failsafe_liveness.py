"""A drone its own lost-link failsafe took over moves on once it hears the ground (ADR
0006's liveness promise, for the drone's own failsafe), as a property over random radio
shadows.

Each example flies drone01 up to a height, out to a waypoint and on to a second one,
both absolute positions (as a survey's legs are). Somewhere on the way out its radio
goes dark for a while, longer than its lost-link timeout and shorter than the mission's
`link_grace_s`; its failsafe holds, returns or lands it, with or without a hold first,
and it may be anywhere in that when the link comes back. The property: the mission
finishes, with the drone at the second waypoint at the height it flew.

FLEET_FAILSAFE_EXAMPLES sets the number of examples (the suite runs a few).
"""

from __future__ import annotations

import asyncio
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dronefleet.agent.link import LostLinkAction, LostLinkPolicy
from dronefleet.compose import SimField
from dronefleet.sim.radio import RadioModel
from tests.mission.test_bundles import beyond_home, fire_world, fly, radio_shadow

EXAMPLES = int(os.environ.get("FLEET_FAILSAFE_EXAMPLES", "8"))
GRACE_S = 30.0  # mission.link_grace_s, the default: a shadow ends within it


@pytest.mark.slow(EXAMPLES // 2)
@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    height_m=st.integers(6, 20),
    out_m=st.integers(25, 60),
    dark_from_m=st.floats(3.0, 24.0),
    dark_s=st.floats(4.0, GRACE_S - 4.0),
    action=st.sampled_from(["hold", "return", "land"]),
    hold_first_s=st.sampled_from([0.0, 3.0, 10.0]),
)
def test_a_drone_its_failsafe_took_over_reaches_its_next_waypoint_at_its_height(
        height_m: int, out_m: int, dark_from_m: float, dark_s: float, action: LostLinkAction,
        hold_first_s: float) -> None:
    def shadow(sim: SimField) -> None:
        radio_shadow(sim, beyond_home(sim, dark_from_m), dark_s)

    script = f"""
d = assign("drone01")
arm(d)
takeoff(d, {height_m}*m)
first = d.position.target({out_m}*m, 0)
second = first.target(20*m, 90)
move(d, to=first, speed=5*m/s)
move(d, to=second, speed=5*m/s)
print(f"at {{d.rel_alt:.1f}} m, {{d.position.distance(second):.1f}} m off")
"""
    policy = LostLinkPolicy(timeout_s=3, action=action, return_after_s=hold_first_s)
    _, (record, log), ground = asyncio.run(fly(script, fire_world(RadioModel()), max_s=400, prepare=shadow,
                                               lost_link=policy))
    assert record.status == "finished", "\n".join(log + ["--- ground:"] + ground[-25:])
    where = next(line for line in log if line.startswith("at "))
    alt, off = float(where.split()[1]), float(where.split()[3])
    assert abs(alt - height_m) < 1.0 and off < 1.5, "\n".join(log)
