"""A preflight is bounded as a mission is (issue 75): its child process (`fleet mission
simulate`, real) has the sandbox's memory limit and a wall bound. At the bound, a script
still computing at its own line is stopped there and named; a simulation still flying
is judged as far as it got. Fast: one drone, small bounds, no fleet."""

from __future__ import annotations

import pytest

from dronefleet.ground.planning import Bounds, SimulationBound, predict
from dronefleet.sim.world import DroneSpec, Spot, World

pytestmark = pytest.mark.integration

WORLD = World(origin=Spot(lat=40.6334, lon=-8.6608, alt=8.2), drones=[DroneSpec(id="drone01", lat=40.6334, lon=-8.6608, alt=8.2)])
# The wall bound counts the child's start too (about 1 s of imports, more on a loaded machine)
BOUNDS = Bounds(wall_s=5.0, memory_mb=512, cpu_s=10.0)


@pytest.mark.parametrize(("source", "line"), [
    ("d = assign()\nx = 0\nwhile True:\n    x += 1\n", {3, 4}),  # a Python loop that never waits
    ("d = assign()\nprint(sum(range(10**12)))\n", {2}),  # a spin inside one C call
], ids=["python-loop", "c-call"])
async def test_a_script_computing_at_its_bound_is_stopped_there_and_its_line_named(source: str, line: set[int]) -> None:
    with pytest.raises(SimulationBound) as bound:
        await predict(source, WORLD, 1800, None, BOUNDS)
    assert bound.value.line in line, bound.value
    assert bound.value.wall_s == BOUNDS.wall_s


async def test_a_memory_bomb_ends_the_simulated_mission_as_the_sandbox_ends_it() -> None:
    prediction = await predict("d = assign()\nx = ' ' * (8 * 1024**3)\n", WORLD, 1800, None, BOUNDS)
    assert (prediction.status, prediction.cause) == ("failed", "security"), prediction
    assert "line 2" in prediction.message, prediction


async def test_a_mission_that_waits_on_its_drones_is_not_the_bound_s_business() -> None:
    """A long survey outlasts a 1-s bound in fast time: stopped while flying, no line named."""
    survey = "d = assign()\narm(d)\ntakeoff(d, 10*m)\nfor i in range(400):\n    move(d, forward=50*m)\n    turn(d, by=90*deg)\n"
    with pytest.raises(SimulationBound) as bound:
        await predict(survey, WORLD, 7200, None, Bounds(wall_s=1.0, memory_mb=512))
    assert bound.value.line is None, bound.value
