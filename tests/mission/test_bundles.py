"""Task bundles (issue 14, SPEC §6): validation, the agent's runner, the ground's view,
the mission's `push` — in fast time (the real GroundStation, agents and mission runtime
on the memory bus and the virtual clock; the radio model where the link matters).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any

import pytest

from dronefleet.agent.config import AgentConfig
from dronefleet.agent.link import LostLinkPolicy
from dronefleet.compose import SimField
from dronefleet.mission.lifecycle.delivery import OVERDUE_S
from dronefleet.schemas.bundles import MAX_STEPS, parse_bundle
from dronefleet.schemas.errors import CommandRejected, InvalidMessage
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.heat_field import HeatSource
from dronefleet.sim.radio import RadioModel, Spot3
from dronefleet.sim.world import DroneSpec, Spot, World
from tests.waiting import advance_until

BASE = (40.633490, -8.660815)


def bundle(*steps: dict[str, Any], **fields: Any) -> bytes:
    return json.dumps({"drone_id": "drone01", "timestamp": 1, "bundle_id": "b1", "steps": list(steps), **fields}).encode()


# ---- validation: the whole bundle, refusals name the step and field ------------------


@pytest.mark.parametrize(("steps", "fields", "reason", "field"), [
    ([{"cmd": "takeoff"}, {"cmd": "fly"}], {}, "step 1: unknown command 'fly'", "$.steps[1].cmd"),
    ([{"cmd": "goto", "lat": 40.6, "lon": -8.6}] * 4 + [{"cmd": "goto", "lat": 95, "lon": -8.6}], {},
     "step 4: lat: Expected `float` <= 90.0", "$.steps[4].lat"),
    ([{"cmd": "takeoff", "alt": "high"}], {}, "step 0: alt: Expected `float | null`, got `str`", "$.steps[0].alt"),
    ([{"wait_s": -1}], {}, "step 0: wait_s: seconds between 0 and 86400", "$.steps[0].wait_s"),
    ([{"cmd": "land", "until": {"field": "sensor.temperature", "op": "~", "value": 3}}], {},
     "step 0: until.op: '~' is not one of", "$.steps[0].until.op"),
    ([{"cmd": "land", "until": {"any": [{"field": "battery", "op": "<", "value": 0.3}]}}], {},
     "step 0: until.any[0].field: no field 'battery'; did you mean battery.remaining_percent", "$.steps[0].until.any[0].field"),
    ([{"cmd": "land", "until": {"field": "speed", "op": ">"}}], {}, "step 0: until: missing value", "$.steps[0].until"),
    ([{"cmd": "land", "command_id": "x"}], {}, "step 0: command_id: set by the bundle", "$.steps[0].command_id"),
    ([{"cmd": "land"}] * (MAX_STEPS + 1), {}, f"steps: at most {MAX_STEPS}", "$.steps"),
    ([], {}, "steps: a bundle needs at least one step", "$.steps"),
    ([{"cmd": "land"}], {"until": {"field": "armed", "op": "==", "value": 1}}, "until.value: armed is a bool", "$.until.value"),
    ([{"cmd": "land"}], {"on_link_loss": "panic"}, "Invalid enum value 'panic'", "$.on_link_loss"),
])
def test_an_invalid_bundle_is_refused_whole_naming_step_and_field(
    steps: list[dict[str, Any]], fields: dict[str, Any], reason: str, field: str
) -> None:
    with pytest.raises(InvalidMessage) as caught:
        parse_bundle(bundle(*steps, **fields))
    assert caught.value.reason.startswith(reason), caught.value.reason
    assert caught.value.field == field


def test_the_spec_example_parses_with_its_guards() -> None:
    parsed = parse_bundle(bundle(
        {"cmd": "takeoff", "alt": 10},
        {"cmd": "goto", "lat": 40.6337, "lon": -8.6605, "until": {"any": [
            {"field": "sensor.temperature", "op": ">", "value": 37}, {"field": "position.rel_alt", "op": "<", "value": 2}]}},
        {"wait_s": 5}, {"cmd": "return"},
        on_link_loss="continue", timeout_s=600, until={"field": "battery.remaining_percent", "op": "<", "value": 0.3},
    ))
    assert [s.name for s in parsed.steps] == ["takeoff", "goto", "wait", "return"]
    assert str(parsed.steps[1].until) == "(sensor.temperature > 37 or position.rel_alt < 2)"
    assert str(parsed.until) == "battery.remaining_percent < 0.3"
    values = {"sensor.temperature": 39.5, "position.rel_alt": 10.0}
    assert parsed.steps[1].until is not None and parsed.steps[1].until.holds(values.get)
    assert not parsed.steps[1].until.holds({"position.rel_alt": 10.0}.get)  # no reading yet: not hot


# ---- fast time ------------------------------------------------------------------------


def fire_world(radio: RadioModel | None = None) -> World:
    """drone01 (temperature) at BASE; a fire 150 m north whose 37 °C edge is ~110 m out."""
    lat, lon = destination(*BASE, 150, 0.0)
    return World(
        origin=Spot(lat=BASE[0], lon=BASE[1], alt=8.2), ground_station=Spot(lat=BASE[0], lon=BASE[1]),
        drones=[DroneSpec(id="drone01", lat=BASE[0], lon=BASE[1], sensors=["temperature"]),
                DroneSpec(id="drone02", lat=BASE[0], lon=destination(*BASE, 6, 90.0)[1])],
        environment_temp=20, heat_sources=[HeatSource(lat=lat, lon=lon, radius=100, temp=60)], radio=radio,
    )


async def fly(script: str, world: World | None = None, max_s: float = 900, prepare: Callable[[SimField], Any] | None = None,
              **agent: Any) -> tuple[SimField, Any, list[str]]:
    sim = SimField(world or fire_world(), seed=3, agent_config=AgentConfig(telemetry_rate_ms=200, **agent))
    if prepare is not None:
        prepare(sim)
    await sim.start()
    try:
        record = await sim.run_mission(script, max_s=max_s)
        log = [line.message for line in sim.mission_log(record.mission_id)]
        ground = [f"{line.drone_id}: {line.message}" for _, line in sim.events.query()]
        return sim, (record, log), ground
    finally:
        await sim.close()


PATROL = """
d = assign("drone01")
arm(d)
r = push(d, [step.takeoff(10*m),
             step.move(forward=400*m, speed=8*m/s, until=when.sensor.temperature > 37),
             step.wait(2*s),
             step.move(backward=20*m)],
         timeout=300*s)
assert r.state == "done", r
assert r.steps_done == 4
guarded = [e for e in r.history if e.state == "guard"]
assert len(guarded) == 1 and guarded[0].step == 1 and guarded[0].reason.startswith("sensor.temperature > 37"), r.history
assert d.sensor.temperature > 25  # 20 m back from the guard: warmer than the field's 20 °C
home(d)
"""


async def test_a_patrol_bundle_ends_its_sweep_on_the_guard_and_the_mission_gets_the_record() -> None:
    _, (record, log), ground = await fly(PATROL)
    assert record.status == "finished", (record, log)
    starts = [g for g in ground if "Bundle b-" in g and " step " in g and "/4: " in g]
    assert [s.split(":", 2)[1].split()[-1] for s in starts] == ["1/4", "2/4", "3/4", "4/4"], starts
    assert "Takeoff with altitude 10.0m" in starts[0] and "Move 20 m backward" in starts[3] and "Wait 2 s" in starts[2], starts
    assert any("step 2/4 ended by sensor.temperature > 37" in g for g in ground), ground
    assert any(g.endswith("done (4 steps)") for g in ground), ground


async def test_the_bundles_own_guard_ends_it_and_says_which() -> None:
    script = """
d = assign("drone01")
arm(d)
r = push(d, [step.takeoff(10*m), step.move(forward=400*m, speed=8*m/s), step.move(forward=10*m)],
         until=(when.sensor.temperature > 45) | (when.battery.remaining_percent < 0.01))
assert r.state == "ended" and r.step == 1, r
assert r.ended_by.startswith("sensor.temperature > 45"), r.ended_by
assert r.steps_done == 1
home(d)
"""
    _, (record, log), ground = await fly(script)
    assert record.status == "finished", (record, log)
    assert any("ended by sensor.temperature > 45" in g and "at step 2" in g for g in ground), ground


async def test_a_command_from_the_ground_cancels_the_bundle_mid_step() -> None:
    sim = SimField(fire_world(), seed=3, agent_config=AgentConfig(telemetry_rate_ms=200))
    await sim.start()
    try:
        await sim.station.command("drone01", b'{"cmd": "arm"}')
        reply = await sim.station.push("drone01", bundle({"cmd": "takeoff", "alt": 10}, {"cmd": "move", "y": 300}, bundle_id="b7"))
        assert reply.accepted and reply.bundle_id == "b7"
        registry = sim.station.registry
        await advance_until(sim, lambda: (registry.info("drone01").bundle or _NO).step == 1, 120)
        info = registry.info("drone01").bundle
        assert info is not None and info.steps == 2 and info.description == "Move 300 m forward"
        await sim.station.command("drone01", b'{"cmd": "cancel"}')
        await advance_until(sim, lambda: registry.info("drone01").bundle is None, 10)
        record = await sim.station.bundle_record("drone01", "b7")
        assert record.state == "cancelled" and record.step == 1 and record.reason == "cancel from the ground", record
        assert [e.state for e in record.history] == ["start", "finish", "start", "cancel"]
        with pytest.raises(CommandRejected) as unknown:
            await sim.station.bundle_record("drone01", "nope")
        assert unknown.value.status == 404 and "no bundle 'nope'" in unknown.value.reason
        with pytest.raises(CommandRejected) as twice:  # ids are the drone's record: never reused
            await sim.station.push("drone01", bundle({"cmd": "land"}, bundle_id="b7"))
        assert twice.value.status == 409 and "exists already" in twice.value.reason
        # the same bundle sent again (an answer lost): answered as before, not run again
        again = await sim.station.push("drone01", bundle({"cmd": "takeoff", "alt": 10}, {"cmd": "move", "y": 300}, bundle_id="b7"))
        assert again.accepted and again.reason == "bundle b7 accepted before (cancelled)", again
        assert (await sim.station.bundle_record("drone01", "b7")).history == record.history
    finally:
        await sim.close()


class _No:
    step = -1


_NO = _No()


async def test_a_guard_on_a_sensor_the_drone_does_not_carry_is_refused_at_the_ground() -> None:
    sim = SimField(fire_world(), seed=3, agent_config=AgentConfig(telemetry_rate_ms=200))
    await sim.start()
    try:
        with pytest.raises(InvalidMessage) as caught:
            await sim.station.push("drone02", bundle(
                {"cmd": "takeoff"}, {"cmd": "move", "y": 10, "until": {"field": "sensor.temperature", "op": ">", "value": 37}},
                drone_id="drone02"))
        assert caught.value.reason.startswith("step 1: until.field: drone02 carries no temperature sensor"), caught.value.reason
        assert caught.value.field == "$.steps[1].until.field"
    finally:
        await sim.close()


SURVEY = """
d = assign("drone01")
arm(d)
r = push(d, [step.takeoff(10*m), step.move(forward=160*m, speed=8*m/s), step.wait(3*s), step.move(backward=160*m, speed=8*m/s)],
         on_link_loss=POLICY, timeout=200*s)
print_state = (r.state, r.steps_done, [(e.step, e.state) for e in r.history])
assert r.state == WANT, print_state
assert [e.state for e in r.history] == HISTORY, print_state  # every event, also those sent out of reach
home(d)
"""


@pytest.mark.parametrize(("policy", "want", "history"), [
    ("continue", "done", ["start", "finish"] * 4 + ["done"]),
    ("return", "ended", ["start", "finish", "start", "guard"]),
])
async def test_a_survey_beyond_radio_range_runs_alone_and_the_mission_catches_up(policy: str, want: str, history: list[str]) -> None:
    script = SURVEY.replace("POLICY", repr(policy)).replace("WANT", repr(want)).replace("HISTORY", repr(history))
    runs = []
    for _ in range(2):  # deterministic per seed
        sim, (record, log), ground = await fly(script, fire_world(RadioModel()), lost_link=LostLinkPolicy(timeout_s=3, action="hold"))
        assert record.status == "finished", (record, log, ground)
        runs.append((record.status, log, ground))
        # The drone noticed: its link_lost status if it got out before the link closed,
        # and in any case its link_restored, which tells how long it was without the ground.
        assert any("Link to ground station restored: after" in g for g in ground), ground
        if policy == "continue":  # it flew on, out of reach: the ground lost it, the mission waited
            assert any("Link lost" in g for g in ground), ground
            assert any("link lost while it runs bundle" in line for line in log), log
            assert any("link restored" in line for line in log), log
            # The ground's log catches up with what it did not hear, and is not left at step 2.
            caught = next(i for i, g in enumerate(ground) if "Bundle b-m1-1: caught up on" in g)
            assert any("Bundle b-m1-1 step 3/4: Wait 3 s" in g for g in ground[caught:]), ground
            assert any("Bundle b-m1-1 done (4 steps)" in g for g in ground), ground
            assert caught > next(i for i, g in enumerate(ground) if "Link lost" in g)
        else:  # it turned home at once
            assert any("Bundle b-m1-1 ended by link lost (on_link_loss=return) at step 2" in g for g in ground), ground
            assert any("Start return to launch" in g for g in ground), ground
    assert runs[0] == runs[1]


async def example(script: str, world: str, seed: int, max_s: float) -> tuple[Any, list[str], list[str], dict[str, Any]]:
    """An example script on its world in fast time: record, mission log, ground log, result."""
    from dronefleet import examples
    from dronefleet.sim.world import load_world

    sim = SimField(load_world(examples.WORLDS / world), seed=seed)
    await sim.start()
    try:
        record = await sim.run_mission((examples.DIR / script).read_text(), max_s=max_s)
        log = [line.message for line in sim.mission_log(record.mission_id)]
        return record, log, [line.message for _, line in sim.events.query()], sim.result(record)
    finally:
        await sim.close()


async def test_the_fire_patrol_example_sweeps_as_a_bundle_then_traces_from_the_ground() -> None:
    record, log, ground, _ = await example("fire_patrol_bundle.py", "fire.yml", seed=1, max_s=1200)
    assert record.status == "finished", log
    assert any(m.startswith("the drone ended its sweep at step") and m.endswith("sensor.temperature > 37") for m in log), log
    assert "perimeter traced: back where it reached the contour" in log, log
    assert any("Bundle b-m1-1 ended by sensor.temperature > 37" in m for m in ground), ground


async def test_the_survey_example_flies_beyond_radio_range_and_the_mission_gets_every_step() -> None:
    record, log, _, result = await example("survey_bundle.py", "survey.yml", seed=3, max_s=600)
    assert record.status == "finished", log
    assert "survey done: 11 of 11 steps, 23 events in the drone's record" in log, log
    assert any("link lost while it runs bundle b-m1-1" in m for m in log), log
    track = result["drones"]["drone01"]
    far = max(distance_m(*BASE, s["lat"], s["lon"]) for s in track["flown"])
    heard = max(distance_m(*BASE, s["lat"], s["lon"]) for s in track["samples"])
    assert far > 150 and heard < 100, (far, heard)  # it surveyed where the ground could not hear it
    assert distance_m(*BASE, track["flown"][-1]["lat"], track["flown"][-1]["lon"]) < 3  # and came home


async def test_the_missions_own_command_during_a_bundle_supersedes_its_step_and_cancels_it() -> None:
    script = """
d = assign("drone01")
arm(d)
outcome = {}
def patrol():
    outcome["r"] = push(d, [step.takeoff(10*m), step.move(forward=300*m, speed=5*m/s), step.home()])
p = run(patrol)
while d.cmd is None or d.cmd.name != "move":  # the bundle's second step is flying
    wait(d)
cancel(d)  # as SPEC §2: a cancel supersedes the running move - and ends the bundle
wait(p)
r = outcome["r"]
assert r.state == "cancelled" and r.step == 1 and r.reason == "cancel from the ground", r
assert [e.state for e in r.history] == ["start", "finish", "start", "cancel"], r.history
home(d)
"""
    _, (record, log), ground = await fly(script)
    assert record.status == "finished", (record, log)
    assert any("Bundle b-m1-1 cancelled at step 2/3: cancel from the ground" in g for g in ground), ground


async def test_a_command_that_ends_out_of_reach_reaches_the_mission_when_the_link_is_back() -> None:
    """Not a bundle: a single move whose `finish` the drone publishes beyond radio range.
    Back in range (its lost-link failsafe brings it home) the agent repeats the statuses
    the ground missed, so the verb returns instead of waiting for ever."""
    script = """
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=115*m, speed=8*m/s)
print("the move returned")
"""
    _, (record, log), ground = await fly(script, fire_world(RadioModel()), max_s=300,
                                         # 6 s: the move ends (15 m past the radio's range) before the failsafe
                                         lost_link=LostLinkPolicy(timeout_s=6, action="hold", return_after_s=4))
    assert any("Link lost" in g for g in ground), ground  # the finish was published out of reach
    assert "the move returned" in log, (record, log)



def first_home(sim: SimField) -> tuple[float, float]:
    """Where the world's first drone starts (the tests' worlds place it)."""
    spec = sim.world.drones[0]
    assert spec.lat is not None and spec.lon is not None
    return spec.lat, spec.lon


def beyond_home(sim: SimField, metres: float) -> Callable[[Spot3], bool]:
    """Whether a spot is farther than `metres` across from the first drone's home."""
    home = first_home(sim)
    return lambda spot: distance_m(*home, spot.lat, spot.lon) > metres


def radio_shadow(sim: SimField, begins: Callable[[Spot3], bool], lasts_s: float, after_s: float = 0.0) -> dict[str, float]:
    """drone01's messages are lost for `lasts_s`, from `after_s` after `begins(where it
    is)` first holds; the returned dict gets "from", the shadow's start."""
    assert sim.air is not None
    shadow: dict[str, float] = {}

    def lost(src: str, dst: str, stream: str) -> bool:
        if "drone01" not in (src, dst):
            return False
        now = sim.clock.monotonic()
        if "from" not in shadow and begins(sim._where()["drone01"]):
            shadow["from"] = now + after_s
        return 0 <= now - shadow.get("from", now + 1) < lasts_s

    sim.air.interference = lost
    return shadow


SEVENTEEN_M_OUT = """
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=17*m, speed=2*m/s)
print("the move returned")
"""


async def test_a_status_lost_in_a_short_gap_is_repeated_when_probes_are_answered_again(caplog: pytest.LogCaptureFixture) -> None:
    """A radio shadow 16 m out silences drone01 for 3 s, shorter than the lost-link
    timeout (5 s), just as its move publishes `finish` there: the status is lost with the
    link. Once a probe is answered again the agent repeats what it published since the
    last answered one, so the verb returns (without the repeat it waits for ever)."""
    shadows: list[dict[str, float]] = []

    def sixteen_metres_out(sim: SimField) -> None:
        shadows.append(radio_shadow(sim, beyond_home(sim, 16), 3.0))

    caplog.set_level(logging.INFO, logger="dronefleet.agent.runtime")
    _, (record, log), _ = await fly(SEVENTEEN_M_OUT, fire_world(RadioModel()), max_s=120, prepare=sixteen_metres_out)
    assert "from" in shadows[0]
    assert "the move returned" in log, (record, log)
    assert any("repeating" in r.getMessage() for r in caplog.records)
    # A 3 s gap may have been the mesh routing the drone another way: its command
    # queryables were declared afresh (ADR 0003).
    assert any("declaring its command queryables afresh" in r.getMessage() for r in caplog.records)


async def test_a_repeat_lost_as_the_link_relapses_is_repeated_at_the_next_contact(caplog: pytest.LogCaptureFixture) -> None:
    """Seen on examples/gas_alarm.py (seed 38): a move's `finish` was lost in a gap, its
    repeat at the next answered probe was lost too as the link dropped again at once,
    and the contact after that repeated only what was newer — the verb waited for ever.
    Here: drone01 is silent for 3 s as the finish is published, its statuses are lost
    for 2 s after (the repeat), then it is silent again for 2.5 s. The agent repeats
    the finish again after the second gap, as the link had not held since the first."""
    windows: dict[str, float] = {}

    def relapsing(sim: SimField) -> None:
        assert sim.air is not None
        home = first_home(sim)

        def lost(src: str, dst: str, stream: str) -> bool:
            if "drone01" not in (src, dst):
                return False
            now = sim.clock.monotonic()
            if "from" not in windows and distance_m(*home, sim._where()["drone01"].lat, sim._where()["drone01"].lon) > 16:
                windows["from"] = now
            t = now - windows.get("from", now + 1)
            return 0 <= t < 3 or (3 <= t < 5 and stream.endswith("/status")) or 5 <= t < 7.5

        sim.air.interference = lost

    caplog.set_level(logging.INFO, logger="dronefleet.agent.runtime")
    _, (record, log), _ = await fly(SEVENTEEN_M_OUT, fire_world(RadioModel()), max_s=120, prepare=relapsing)
    assert "from" in windows
    assert "the move returned" in log, (record, log)
    repeats = [r.getMessage() for r in caplog.records if "repeating" in r.getMessage() and "drone01" in r.getMessage()]
    assert len(repeats) >= 2, repeats


async def test_a_verb_sent_while_its_drone_is_out_of_reach_waits_for_the_link() -> None:
    """The ground refuses commands to a drone it marks unknown (409); a mission verb
    sent then waits, within mission.link_grace_s, for the drone to be back instead of
    failing the mission. A 12 s radio shadow hides drone01 once it hovers."""
    def once_it_hovers(sim: SimField) -> None:  # 5 s after it passes 9.5 m: its takeoff has ended
        radio_shadow(sim, lambda spot: spot.alt > 8.2 + 9.5, 12.0, after_s=5.0)

    _, (record, log), _ = await fly("""
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
print("took off")
while d.state != "unknown":
    sleep(0.2*s)
print("out of reach")
land(d)
print("landed")
""", fire_world(RadioModel()), max_s=120, prepare=once_it_hovers)
    assert record.status == "finished", (record, log)
    assert log.index("took off") < log.index("out of reach") < log.index("drone01: land waits for the link to come back") < log.index("landed"), log


TAKEN_BACK = "drone01: its lost-link failsafe is flying it home; stopping that to send goto again, as it hears the ground"


@pytest.mark.parametrize(("action", "said"), [
    ("hold", "drone01: goto was interrupted by the drone's lost-link failsafe; sending it again"),
    ("return", TAKEN_BACK),
])
async def test_a_goto_its_lost_link_failsafe_interrupted_is_sent_again_when_the_link_is_back(action: str, said: str) -> None:
    """A 7 s radio shadow, 20 m into a 60 m move, outlasts the lost-link timeout (3 s):
    the agent's failsafe holds (or turns home), which cancels the move. The mission sends
    it again once the drone is back, so the verb returns with the drone at its goal
    (before, the cancel ended the verb there and the drone stayed short of it). A drone
    turning home refuses a goto ("returning"): the mission stops that return first
    (before, it ended cmd_exec "goto drone01 refused: returning": corpus worlds 63, 95, 123)."""
    def twenty_metres_out(sim: SimField) -> None:
        radio_shadow(sim, beyond_home(sim, 20), 7.0)

    sim, (record, log), _ = await fly("""
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
start = d.position
move(d, forward=60*m, speed=5*m/s)
print(f"moved {start.distance(d.position):.0f} m")
""", fire_world(RadioModel()), max_s=200, prepare=twenty_metres_out,
        lost_link=LostLinkPolicy(timeout_s=3, action=action, return_after_s=60))  # type: ignore[arg-type]
    assert record.status == "finished", (record, log)
    assert said in log, log
    moved = next(line for line in log if line.startswith("moved"))
    assert abs(float(moved.split()[1]) - 60) < 3, log


async def test_a_goto_sent_while_the_failsafe_flies_the_drone_home_takes_it_back() -> None:
    """The failsafe's return began while the mission sent nothing (a
    worker held at its chain's edge): the next goto, refused "returning", stops that
    return once the drone hears the ground and goes (the mission never sent it home)."""
    def once_it_hovers(sim: SimField) -> None:
        radio_shadow(sim, lambda spot: spot.alt > 8.2 + 9.5, 8.0, after_s=5.0)

    _, (record, log), _ = await fly("""
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
while d.state != "unknown":
    sleep(0.2*s)
while d.state == "unknown":
    sleep(0.2*s)
print("back")
move(d, forward=20*m, speed=5*m/s)
print("moved")
""", fire_world(RadioModel()), max_s=200, prepare=once_it_hovers,
        lost_link=LostLinkPolicy(timeout_s=3, action="return", return_after_s=60))
    assert record.status == "finished", (record, log)
    assert log.index("back") < log.index(TAKEN_BACK) < log.index("moved"), log


async def test_a_lost_link_hold_does_not_stop_a_drone_on_its_way_home(caplog: pytest.LogCaptureFixture) -> None:
    """A 6 s radio shadow (the lost-link timeout is 3 s, action hold) hits drone01 while
    it returns: the hold would stop it in the air, out of reach; the agent lets the
    return go on, so the return ends once (finish), never cancelled."""
    def once_it_heads_home(sim: SimField) -> None:
        home = first_home(sim)
        state = {"out": False}

        def heading_home(spot: Spot3) -> bool:  # out past 30 m, then back inside 25 m
            far = distance_m(*home, spot.lat, spot.lon)
            state["out"] = state["out"] or far > 30
            return state["out"] and far < 25

        radio_shadow(sim, heading_home, 6.0)

    caplog.set_level(logging.WARNING, logger="dronefleet.agent.runtime")
    sim, (record, log), _ = await fly("""
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=35*m, speed=5*m/s)
home(d)
""", fire_world(RadioModel()), max_s=200, prepare=once_it_heads_home,
        lost_link=LostLinkPolicy(timeout_s=3, action="hold", return_after_s=60))
    assert record.status == "finished", (record, log)
    assert "interrupted by the drone's lost-link failsafe" not in "\n".join(log), log
    assert any("hold not taken, the drone is already running return" in r.getMessage() for r in caplog.records)


async def test_a_command_sent_into_a_radio_shadow_waits_for_the_link_instead_of_failing() -> None:
    """CI caught this on the emulated radio: a goto sent just as the link dropped got no
    answer; the resend met the ground's "drone state is unknown" (409) and the mission
    failed, although it had just said it would wait 30 s for the link. Here a 10 s
    shadow begins about a second after drone01 finishes its first hop, as the script
    sends the second: the mission waits for the drone and the second hop flies."""
    def after_the_first_hop(sim: SimField) -> None:
        radio_shadow(sim, beyond_home(sim, 14.5), 10.0, after_s=1.0)

    _, (record, log), _ = await fly("""
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=15*m, speed=5*m/s)
sleep(1*s)
move(d, forward=10*m, speed=5*m/s)
print(f"out at {distance(d.position, d.home):.0f} m")
""", fire_world(RadioModel()), max_s=200, prepare=after_the_first_hop,
        lost_link=LostLinkPolicy(timeout_s=30, action="hold", return_after_s=60))
    assert record.status == "finished", (record, log)
    assert "drone01: goto waits for the link to come back" in log, log
    assert "out at 25 m" in log, log


SUPERSEDED_UNHEARD = """
d = assign("drone01")
arm(d)
takeoff(d, 10*m)


def hold_up_high():
    return push(d, [step.move(up=6*m), step.wait(120*s)])


first = run(hold_up_high)
sleep(15*s)
push(d, [step.move(down=6*m), step.wait(1*s)])
wait(first)
print(f"first: {first.result.state}")
"""


def lossy_up_high(sim: SimField) -> None:
    """drone01's statuses are lost while it is above 12 m (queries still cross)."""
    assert sim.air is not None

    def lost(src: str, dst: str, stream: str) -> bool:
        return src == "drone01" and stream.endswith("/status") and sim.vehicles["drone01"].rel_alt > 12

    sim.air.interference = lost


async def test_a_bundle_whose_end_was_lost_returns_once_past_its_timeout() -> None:
    """A relay's homeward bundle ended while its statuses were lost,
    and nothing else was sent to it: its routine waited to the time limit. Past its
    timeout the mission reads the bundle's record from the agent."""
    script = ('d = assign("drone01")\narm(d)\nr = push(d, [step.takeoff(15*m), step.wait(100*s)], timeout=20*s)\n'
              "print(f'alone: {r.state} {r.reason}')\n")
    _, (record, log), _ = await fly(script, fire_world(RadioModel()), max_s=120, prepare=lossy_up_high)
    assert record.status == "finished", (record, log)
    assert "alone: failed timeout: not done within 20 s" in log, log
    assert record.start is not None and record.end is not None
    assert (record.end - record.start) / 1000 < 20 + OVERDUE_S + 15, record  # takeoff, timeout, then one read


async def test_a_bundle_ended_by_the_next_one_returns_though_its_end_was_lost() -> None:
    """A relay's duty bundle was superseded by the next one while its
    statuses were lost, and its push waited until the time limit. A bundle (or command)
    the drone accepts ends the one it ran; the mission reads that one's record again.
    Here drone01's statuses are lost while it is above 12 m: the first bundle's end."""
    _, (record, log), _ = await fly(SUPERSEDED_UNHEARD, fire_world(RadioModel()), max_s=300, prepare=lossy_up_high)
    assert "first: cancelled" in log, (record, log)


async def test_a_drone_its_failsafe_brought_home_takes_off_again_for_the_next_command() -> None:
    """A 25 s radio shadow, the drone hovering 20 m out at 12 m: its lost-link failsafe
    (3 s, then return) flies it home, where it lands and disarms. Once it hears the
    ground again the script sends it to its next waypoint (absolute, as a survey's
    are): the mission arms it and takes it back up to the height it had before the
    failsafe, then sends the goto (before, the goto was refused "disarmed" and the
    mission failed cmd_exec)."""
    def once_it_is_out(sim: SimField) -> None:
        radio_shadow(sim, beyond_home(sim, 19.5), 25.0, after_s=2.0)

    _, (record, log), _ = await fly("""
d = assign("drone01")
arm(d)
takeoff(d, 12*m)
move(d, forward=20*m, speed=5*m/s)
waypoint = d.position.target(10*m, 0)
while d.state != "unknown":
    sleep(0.2*s)
while d.state == "unknown":
    sleep(0.2*s)
print(f"back, armed {d.armed}")
move(d, to=waypoint)
print(f"there at {d.rel_alt:.0f} m, {d.position.distance(waypoint):.0f} m off")
""", fire_world(RadioModel()), max_s=300, prepare=once_it_is_out,
        lost_link=LostLinkPolicy(timeout_s=3, action="return", return_after_s=0))
    assert record.status == "finished", "\n".join(log)
    relaunched = next(line for line in log if "brought it home" in line)
    assert log.index("back, armed False") < log.index(relaunched), log
    assert "there at 12 m, 0 m off" in log, "\n".join(log)
