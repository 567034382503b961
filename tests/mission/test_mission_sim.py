"""Missions in fast time: examples, every cause the runtime produces, concurrency.

A real GroundStation, agents with the sim adapter and the mission runtime, joined by
the memory bus under a VirtualClock (SPEC §5 fast-time simulation). Faults come from
the world file, as an operator would script them.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import json
import subprocess
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, cast

import msgspec
import pytest

from dronefleet.bus.faulty import FaultyBus
from dronefleet.bus.port import Bus, Unreachable
from dronefleet.compose import SimField
from dronefleet.ground.station import GroundStation
from dronefleet.mission.lifecycle.fleet_port import GroundPort
from dronefleet.mission.lifecycle.record import MissionRecord
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.geo import distance_m
from dronefleet.sim.projection import LocalFrame
from dronefleet.sim.world import Fault, World
from tests.waiting import advance_until

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
FLY = "d = assign()\narm(d)\ntakeoff(d, 10*m)\n"


def world_with(faults: list[Fault] | None = None, n: int = 2) -> World:
    base = World().spawn(n)
    if faults:
        base[0] = msgspec.structs.replace(base[0], faults=faults)
    return World(drones=base)


async def fly(
    script: str,
    world: World | None = None,
    *,
    during: Callable[[SimField, str], Awaitable[None]] | None = None,
    max_s: float = 600,
    fleet_port: Callable[[GroundStation], GroundPort] | None = None,
    agent_bus: Callable[[str, Bus], Bus] | None = None,
) -> tuple[MissionRecord, SimField, list[str]]:
    """Run `script` to its end; the record, the (closed) field and the mission's log."""
    field = SimField(world or World(), None if world else 2, fleet_port=fleet_port, agent_bus=agent_bus)
    await field.start()
    try:
        if during is None:
            record = await field.run_mission(script, max_s=max_s)
        else:
            assert field.manager is not None
            submitted = field.manager.submit(script)
            runner = asyncio.ensure_future(field.run_mission_started(submitted.mission_id, max_s=max_s))
            await during(field, submitted.mission_id)
            record = await runner
        for drone_id in field.station.registry.ids():
            assert field.station.registry.info(drone_id).mission is None, f"{drone_id} not released"
        return record, field, [line.message for line in field.mission_log(record.mission_id)]
    finally:
        await field.close()


def cause(record: MissionRecord) -> tuple[str, str | None]:
    return record.status, record.cause


# ---- examples ------------------------------------------------------------------------


@pytest.mark.parametrize("example", ["mapping", "replacement_mapping", "two_drones", "synchronisation"])
async def test_examples_finish(example: str) -> None:
    record, _, _ = await fly((EXAMPLES / f"{example}.py").read_text())
    assert cause(record) == ("finished", "success"), record.message


@pytest.mark.integration  # runs `fleet mission simulate` twice as processes
def test_mapping_visits_the_thesis_waypoints_and_replays_identically(tmp_path: Path) -> None:
    outs = []
    for run in ("a", "b"):
        out = tmp_path / run
        done = subprocess.run(
            [sys.executable, "-m", "dronefleet", "mission", "simulate", str(EXAMPLES / "mapping.py"),
             "--drones", "1", "--seed", "7", "--out", str(out)],
            capture_output=True, text=True, timeout=120, cwd=ROOT,
        )
        assert done.returncode == 0, done.stderr + done.stdout
        assert "finished: success" in done.stdout
        outs.append(out)
    first = (outs[0] / "result.json").read_bytes()
    assert first == (outs[1] / "result.json").read_bytes()
    for plot in ("paths.png", "altitude.png", "battery.png", "distances.png"):
        assert (outs[0] / plot).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    result = json.loads(first)
    drone = result["drones"]["drone01"]
    start = drone["samples"][0]
    frame = LocalFrame(start["lat"], start["lon"])
    gotos = [c["target"] for c in drone["commands"] if c["cmd"] == "goto"]
    # Script 5.1, 100 m x 80 m, 2 x 4 steps: sweep east, step north, sweep west, ...
    expected = []
    for row in range(5):
        ys = 20.0 * row
        xs = [50.0, 100.0] if row % 2 == 0 else [50.0, 0.0]
        if row > 0:
            expected.append((100.0 if row % 2 else 0.0, ys))
        expected += [(x, ys) for x in xs]
    planned = [(lambda ne: (ne[1], ne[0]))(frame.to_local(g["lat"], g["lon"])) for g in gotos]
    assert len(planned) == len(expected) == 14
    for (e, n), (ex, ny) in zip(planned, expected, strict=True):
        assert abs(e - ex) < 0.05 and abs(n - ny) < 0.05, (planned, expected)
    # ... and the drone really was at each waypoint (the agent's 0.5 m acceptance radius).
    track = [frame.to_local(s["lat"], s["lon"]) for s in drone["samples"]]
    for ex, ny in expected:
        closest = min(((n - ny) ** 2 + (e - ex) ** 2) ** 0.5 for n, e in track)
        assert closest < 3.0, (ex, ny, closest)  # 1 Hz samples at 5 m/s pass within a few m
    assert result["mission"]["status"] == "finished"
    assert drone["samples"][-1]["rel_alt"] < 0.5


# ---- causes --------------------------------------------------------------------------


SCRIPTED_CAUSES = [
    ("requirements", 'assign("drone09")', "failed", "drone09"),
    ("cmd_exec", "d = assign()\ntakeoff(d)", "failed", "disarmed"),  # the agent refuses
    ("cmd_parse", "d = assign()\narm(d)\ntakeoff(d, -5*m)", "failed", "alt"),
    ("script", "d = assign()\nx = 1\ny = x / 0\n", "failed", "line 3: ZeroDivisionError"),
    ("script", "d = assign()\narm(d)\nh = 10*m + d.battery*s\n", "failed", "line 3: UnitError"),
    ("script", "def bad():\n    sleep(1)\n    raise ValueError('nope')\nh = run(bad)\nsleep(100)\n", "failed", "line 3: ValueError: nope"),
    ("revoked", "d = assign()\nrevoke(d)\narm(d)", "failed", "not assigned"),
    ("revoked", "d = assign()\nrevoke(d)\nprint(d.battery)", "failed", "not assigned"),
    ("irreplaceable", 'd = assign("drone01")\nreplace(d)', "failed", "drone01"),
    ("plugin_missing", 'enable("teleport", speed=50*m/s)', "failed", "teleport"),
]


@pytest.mark.parametrize(
    ("expected", "script", "status", "fragment"), SCRIPTED_CAUSES,
    ids=[f"{c}-{i}" for i, (c, *_) in enumerate(SCRIPTED_CAUSES)],
)
async def test_scripted_causes(expected: str, script: str, status: str, fragment: str) -> None:
    record, _, _ = await fly(script)
    assert cause(record) == (status, expected), record.message
    assert fragment in (record.message or ""), record.message


async def test_user_cancel_leaves_the_drone_holding_and_released() -> None:
    async def cancel_in_flight(field: SimField, mission_id: str) -> None:
        await field.until(lambda: field.vehicles["drone01"].rel_alt > 5)
        assert field.manager is not None
        field.manager.cancel(mission_id)

    record, field, lines = await fly(FLY + "move(d, forward=200*m)\n", world_with(), during=cancel_in_flight)
    assert cause(record) == ("cancelled", "user")
    assert any(line.startswith("drone01: hold at mission end, at 40.633") for line in lines), lines


@pytest.mark.parametrize(("fault", "expected"), [
    (Fault(at_s=15, fault="rc_takeover"), ("cancelled", "manual")),
    (Fault(at_s=15, fault="health_failure", value="gyrometer"), ("failed", "drone_error")),
    (Fault(at_s=15, fault="low_battery", value=0.08), ("cancelled", "return")),
])
async def test_drone_events_end_the_mission(fault: Fault, expected: tuple[str, str]) -> None:
    record, _, _ = await fly(FLY + "move(d, forward=200*m)\nsleep(100)\n", world_with([fault]))
    assert cause(record) == expected, record.message


async def test_a_health_flag_that_drops_for_a_moment_in_flight_is_a_warning_not_the_end() -> None:
    """Issue 58: global_position failing for 1.5 s in flight (a real PX4 did so once,
    flying normally) warns on the drone and the mission goes on; failing for good, it
    fails the mission drone_error (test_drone_events_end_the_mission)."""
    world = world_with([Fault(at_s=15, fault="health_failure", value="global_position"),
                        Fault(at_s=16.5, fault="health_ok")])
    field = SimField(world)
    await field.start()
    try:
        record = await field.run_mission(FLY + "move(d, forward=60*m)\nland(d)\n", max_s=600)
        assert cause(record) == ("finished", "success"), record.message
        said = [f"{row.level} {row.message}" for _, row in field.station.events.query(["drone01"])]
        assert "warn Health check failing: global_position" in said, said
        assert not any("Failed health check" in line for line in said), said
    finally:
        await field.close()


async def test_critical_battery_fails_and_sends_the_drone_home() -> None:
    """The autopilot's critical-battery return ends the mission as the drone's own
    decision, and the drone lands at home (this world is seeded: one outcome)."""
    world = world_with([Fault(at_s=15, fault="low_battery", value=0.03)])
    field = SimField(world)
    await field.start()
    try:
        record = await field.run_mission(FLY + "sleep(100)\n", max_s=600)
        assert cause(record) == ("cancelled", "return"), record.message
        vehicle = field.vehicles["drone01"]
        await advance_until(field, lambda: vehicle.landed_state == "on_ground" and not vehicle.armed, 300)
        assert distance_m(vehicle.lat, vehicle.lon, vehicle.home.lat, vehicle.home.lon) < 1.0
    finally:
        await field.close()


async def test_link_lost_after_the_grace_when_the_agent_dies() -> None:
    killed_at: list[float] = []

    async def kill(field: SimField, mission_id: str) -> None:
        await field.until(lambda: field.vehicles["drone01"].rel_alt > 5)
        field.kill_agent("drone01")
        killed_at.append(field.clock.time_ms())

    record, field, lines = await fly(FLY + "sleep(100)\n", world_with(), during=kill)
    assert cause(record) == ("failed", "link_lost")
    assert "drone01: link lost; waiting up to 30 s for it to come back" in lines
    # The mission waited the whole grace (30 s default) after the drone went silent.
    assert record.end is not None and record.end - killed_at[0] >= 30_000


class FaultInjection:
    """The ground as missions reach it (SimField's `fleet_port`), with some of its calls
    replaced: each override gets the station's own method and the call's arguments."""

    def __init__(self, station: GroundStation, **overrides: Callable[..., Awaitable[Any]]) -> None:
        self._station = station
        for name, fault in overrides.items():
            setattr(self, name, functools.partial(fault, getattr(station, name)))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._station, name)


def inject(**overrides: Callable[..., Awaitable[Any]]) -> Callable[[GroundStation], GroundPort]:
    return lambda station: cast(GroundPort, FaultInjection(station, **overrides))


async def test_unexpected() -> None:
    async def boom(original: Any, *args: Any, **kwargs: Any) -> None:
        raise RuntimeError("station bug")

    record, _, _ = await fly("sleep(5)\nd = assign()\narm(d)\n", world_with(), fleet_port=inject(command=boom))
    assert cause(record) == ("failed", "unexpected")
    assert "station bug" in (record.message or "")


@pytest.mark.parametrize("refusals", [1, 3])
async def test_a_claim_another_mission_won_is_tried_again(refusals: int) -> None:
    """Missions in their own processes pick drones from a copy of the registry: the
    ground refuses a drone another mission claimed meanwhile (409), and the mission
    picks again, up to three times, releasing what it had claimed in that pick."""
    claims: list[str] = []

    async def contested(original: Callable[[str, str], Awaitable[None]], drone_id: str, mission: str) -> None:
        claims.append(drone_id)
        if len(claims) % 2 == 0 and len(claims) <= 2 * refusals:  # the second drone of each pick is taken
            raise CommandRejected(409, f"{drone_id} is assigned to mission m99")
        await original(drone_id, mission)

    record, field, log = await fly("sleep(1)\na, b = assign(any_drone, any_drone)\nprint(a.id, b.id)\n",
                                   world_with(), fleet_port=inject(assign=contested))
    if refusals == 1:
        assert cause(record) == ("finished", "success"), record
        assert "is assigned to mission m99; choosing again" in "\n".join(log), log
        assert len(claims) == 4 and sorted(record.used_drones) == sorted(set(claims)), (claims, record)
    else:
        assert cause(record) == ("failed", "requirements"), record
        assert "could not claim drones" in (record.message or "") and len(claims) == 6, (record, claims)


# ---- runtime behaviour -----------------------------------------------------------------


@pytest.mark.slow(14)
async def test_two_hundred_subroutines_channels_and_stop() -> None:
    script = (
        "hs = [run(lambda i=i: sleep(1 + i % 3)) for i in range(200)]\n"
        "def producer():\n    sleep(3)\n    channel.ready = 42\n"
        "def consumer():\n    return channel.ready + 1\n"
        "c = run(consumer)\nrun(producer)\n"
        "spinner = run(lambda: [None for _ in iter(int, 1)])\n"
        "wait(*hs)\nwait(c)\n"
        "assert c.finished and c.result == 43\n"
        "assert spinner.running\n"
        "stop(spinner)\nwait(spinner)\n"
        "assert spinner.finished and not spinner.running\n"
    )
    record, _, _ = await fly(script)
    assert cause(record) == ("finished", "success"), record.message


async def test_a_subroutine_stopped_before_it_ran_is_finished() -> None:
    """Issue 13: `stop(run(f))` in one breath (a survey stopped at once because the drone
    took off inside the fire) left the subroutine `running` for ever; the mission's end
    then waited a real second for it and logged that it did not stop."""
    script = (
        "survey = run(lambda: sleep(100))\nstop(survey)\nwait(survey)\n"
        "assert survey.finished and not survey.running\n"
    )
    record, _, log = await fly(script)
    assert cause(record) == ("finished", "success"), record.message
    assert not any("did not stop" in line for line in log), log


async def test_any_verb_may_be_handed_to_run_as_a_subroutine() -> None:
    """Issue 56: `wait(run(land, d))` failed the mission with 'call stack is not deep
    enough (in subroutine land)': the verb was the first frame of its subroutine."""
    script = (
        "d = assign(any_drone)\nwait(run(arm, d))\nwait(run(takeoff, d, 5*m))\n"
        "wait(run(land, d))\nprint(f'{d.id} landed')\n"
    )
    record, _, log = await fly(script)
    assert cause(record) == ("finished", "success"), record.message
    assert any(line.endswith("landed") for line in log), log


async def test_the_simulation_time_limit_has_its_own_cause() -> None:
    record, _, log = await fly("while True:\n    sleep(1)\n", max_s=30)
    assert (record.status, record.cause) == ("cancelled", "time_limit"), record
    assert record.message == "simulation time limit of 30 s reached; still running: main: sleep at line 2"
    assert not any("did not stop" in line for line in log), log


async def test_wait_for_telemetry_and_the_drone_wrapper() -> None:
    script = FLY + (
        "seqs = []\n"
        "for _ in range(3):\n    wait(d)\n    seqs.append(d.position.lat)\n"
        "assert d.state == 'hold' and d.armed and d.battery > 0.5, (d.state, d.battery)\n"
        "assert abs(d.rel_alt - 10) < 0.6 and d.home is not None and d.cmd is None\n"
        "p = d.forward(10*m).right(10*m)\n"
        "assert abs(distance(d, p) - 14.14) < 0.2 and abs(bearing(d, p) - 45) < 1, (distance(d, p), bearing(d, p))\n"
        "turn(d, to=p)\nassert abs(d.heading - 45) < 3, d.heading\n"
        "move(d, to=p, speed=2*m/s)\nassert d.distance(p) < 1.0\n"
        "land(d)\n"
    )
    record, _, _ = await fly(script)
    assert cause(record) == ("finished", "success"), record.message


async def test_replacement_mapping_swaps_drones_half_way() -> None:
    from dronefleet.sim.world import load_world

    world = load_world(EXAMPLES / "worlds" / "replacement.yml")
    record, field, lines = await fly((EXAMPLES / "replacement_mapping.py").read_text(), world)
    assert cause(record) == ("finished", "success"), record.message
    assert record.used_drones == ["drone01", "drone02"]
    assert any(line.startswith("Replaced drone01 with drone02: drone02 takes over at") for line in lines), lines
    first = field.vehicles["drone01"]
    assert first.rel_alt < 0.5 and first.position().lat == pytest.approx(first.home.lat, abs=1e-5)


@pytest.mark.parametrize(("failures", "history"), [(3, ["start", "finish", "start", "finish", "done"]), (12, [])])
async def test_a_bundle_record_the_ground_cannot_read_yet_is_asked_again(failures: int, history: list[str]) -> None:
    """Run 46 of issue 31: right after a drone came back in range, its statuses arrived
    while queries found no route for seconds; the mission read no record and made do
    with the end it heard, without the history. It now asks again, a second apart, ten
    times (RECORD_TRIES) before it does."""
    calls: list[str] = []

    async def unreachable_at_first(original: Callable[[str, str], Awaitable[Any]], drone_id: str, bundle_id: str) -> Any:
        calls.append(bundle_id)
        if len(calls) <= failures:
            raise Unreachable(f"no queryable answers drone/{drone_id}/bundle (test)")
        return await original(drone_id, bundle_id)

    script = ("d = assign()\narm(d)\nr = push(d, [step.takeoff(5*m), step.move(forward=10*m)])\n"
              f"assert [e.state for e in r.history] == {history!r}, r.history\n")
    record, _, lines = await fly(script, world_with(), fleet_port=inject(bundle_record=unreachable_at_first))
    assert record.status == "finished", (record, lines)
    assert len(calls) == min(failures + 1, 10)


async def test_a_bundle_a_command_ended_returns_cancelled_though_its_end_and_record_were_lost() -> None:
    """A relay sent home across a flapping link: the command that sent it home ended its
    duty bundle, whose `cancel` went down with the link, and no query reached the drone
    to read the record. The duty bundle's push held the mission open for its time
    limit. The accepted command is the end: once the record stays unread, the push
    returns the bundle cancelled and the log says why."""
    buses: list[FaultyBus] = []

    def bundle_end(key: str, payload: bytes) -> bool:
        status = json.loads(payload)
        return key.endswith("/status") and "bundle_id" in status and status.get("state") == "cancel"

    def lossy(drone_id: str, bus: Bus) -> Bus:
        buses.append(FaultyBus(bus, lose=bundle_end))
        return buses[-1]

    async def unreachable(original: Callable[[str, str], Awaitable[Any]], drone_id: str, bundle_id: str) -> Any:
        raise Unreachable(f"no queryable answers drone/{drone_id}/bundle (test)")

    script = ('d = assign("drone01")\narm(d)\ntakeoff(d, 10*m)\n'
              'duty = run(lambda: push(d, [step.move(forward=5*m), step.wait(600*s)]))\n'
              'sleep(10*s)\nhome(d)\nwait(duty)\nprint(f"duty: {duty.result.state}: {duty.result.reason}")\n')
    record, _, lines = await fly(script, world_with(), max_s=300, agent_bus=lossy,
                                 fleet_port=inject(bundle_record=unreachable))
    assert sum(len(bus.lost) for bus in buses) == 1, "the scenario never lost the bundle's end"
    assert cause(record) == ("finished", "success"), (record, lines)
    assert "duty: cancelled: return from the ground" in lines, lines
    assert any(line.startswith("drone01: could not read bundle ") and line.endswith("it was cancelled: return from the ground")
               for line in lines), lines


@pytest.mark.parametrize(("failures", "ends"), [(2, ("finished", "success")), (3, ("failed", "cmd_exec"))])
async def test_an_unanswered_command_is_sent_again_once_the_drone_is_heard_not_at_once(
        failures: int, ends: tuple[str, str]) -> None:
    """Seen on examples/gas_alarm.py (seed 4): a link just back did not carry queries
    yet and the three tries of a goto went at the same instant, failing the mission.
    Each try again now waits for the drone's next telemetry; a drone that is heard and
    still does not answer three tries fails cmd_exec, as before."""
    tries: list[float] = []
    clock: list[Any] = []

    async def goto_unanswered(original: Callable[..., Awaitable[Any]], drone_id: str, payload: bytes, *args: Any) -> Any:
        if json.loads(payload)["cmd"] == "goto" and len(tries) < failures:
            tries.append(clock[0].monotonic())
            raise Unreachable(f"no queryable answers drone/{drone_id}/cmd (test)")
        return await original(drone_id, payload, *args)

    def port(station: GroundStation) -> GroundPort:
        clock.append(station.clock)
        return inject(command=goto_unanswered)(station)

    script = "d = assign()\narm(d)\ntakeoff(d, 5*m)\nmove(d, forward=10*m)\nland(d)\n"
    record, _, lines = await fly(script, world_with(), fleet_port=port)
    assert cause(record) == ends, (record.message, lines)
    assert len(tries) == failures
    assert all(b > a for a, b in itertools.pairwise(tries)), tries  # not all at once
    assert sum("no answer to goto, sending it again" in line for line in lines) == 2, lines


async def test_a_push_whose_answer_is_lost_is_sent_again_and_runs_once() -> None:
    """A relay's homeward bundle got no answer over a lossy hop; sent
    once only, the plugin's routine unwound and the relay hovered on its spot. The
    push is now sent again as a command is; the agent, which had taken it, answers as
    before and does not run it twice."""
    pushes: list[str] = []

    async def answer_lost(original: Callable[..., Awaitable[Any]], drone_id: str, payload: bytes, *args: Any) -> Any:
        pushes.append(json.loads(payload)["bundle_id"])
        reply = await original(drone_id, payload, *args)
        if len(pushes) == 1:
            raise Unreachable(f"no reply from drone/{drone_id}/bundle within 3 s (test)")
        return reply

    script = ("d = assign()\narm(d)\nr = push(d, [step.takeoff(5*m), step.move(forward=10*m)])\n"
              "assert [e.state for e in r.history] == ['start', 'finish', 'start', 'finish', 'done'], r.history\n")
    record, _, lines = await fly(script, world_with(), fleet_port=inject(push=answer_lost))
    assert record.status == "finished", (record, lines)
    assert len(pushes) == 2 and pushes[0] == pushes[1], pushes
    assert sum("no answer to push, sending it again (2/3)" in line for line in lines) == 1, lines


@pytest.mark.parametrize(("command", "said"), [("goto", "it stands at its target"), ("turn", "it faces its new heading")])
async def test_a_goto_or_turn_whose_end_is_lost_ends_once_the_drone_shows_it(command: str, said: str) -> None:
    """A reliable publication goes down with a link that closes under it; a goto's or a
    turn's `finish` lost with no probe missed (so the agent repeats nothing) hung its verb
    until the time limit (relay corpus worlds, mode chain: a turn of a survey where two
    workers share a way). The verb now ends once the drone is heard standing at its target,
    or facing its new heading, for 10 s, and says so."""
    buses: list[FaultyBus] = []

    def first_finish(key: str, payload: bytes) -> bool:
        status = json.loads(payload)
        return key.endswith("/status") and status.get("command") == command and status.get("state") == "finish" \
            and not any(bus.lost for bus in buses)

    def lossy(drone_id: str, bus: Bus) -> Bus:
        buses.append(FaultyBus(bus, lose=first_finish))
        return buses[-1]

    record, _, log = await fly('d = assign("drone01")\narm(d)\ntakeoff(d)\nmove(d, forward=20*m)\n'
                               'turn(d, to=east)\nmove(d, forward=10*m)\nland(d)\n', max_s=300, agent_bus=lossy)
    assert sum(len(bus.lost) for bus in buses) == 1, f"the scenario never lost a {command}'s finish"
    assert cause(record) == ("finished", "success"), (record, log)
    assert any(f"the end of its {command} was not heard; {said}" in line for line in log), log


async def test_a_drone_whose_command_queryable_never_crossed_is_unreachable_until_asked_to_declare_it_afresh() -> None:
    """Issue 76 in fast time: drone01's agent declares its `cmd` queryable, but the
    declaration never reaches the ground (a FaultyBus loses it). Heard, drone01 is
    `unreachable`, not `ready`; the ground's answer to its next link probe asks it to
    declare its queryables afresh; the other key form crosses, it is ready and flies."""
    buses: list[FaultyBus] = []

    def cmd_never_crosses(drone_id: str, bus: Bus) -> Bus:
        if drone_id != "drone01":
            return bus
        buses.append(FaultyBus(bus, lose_serve=lambda keyexpr: keyexpr == "drone/drone01/cmd"))
        return buses[-1]

    field = SimField(world_with(), None, agent_bus=cmd_never_crosses)
    states: list[str] = []  # drone01's, as the ground lists it
    field.station.listen(lambda e: states.append(e.data.state) if e.kind == "drone" and e.data.drone_id == "drone01" else None)
    await field.start()
    try:
        record = await field.run_mission('d = assign("drone01")\narm(d)\nprint("armed")\n', max_s=120)
        lines = [line.message for line in field.mission_log(record.mission_id)]
        ground = [line.message for _, line in field.events.query() if line.drone_id == "drone01"]
    finally:
        await field.close()
    assert buses[0].lost_serves == ["drone/drone01/cmd"], "the scenario never lost the declaration"
    assert cause(record) == ("finished", "success"), (record, lines)
    assert "armed" in lines, lines
    assert states[0] == "unreachable" and "ready" in states, states
    assert "ready" not in states[:states.index("ready")], states
    reach = [m.split(":")[0].split(" after")[0] for m in ground if m.startswith("Commands")]
    assert reach == ["Commands cannot reach it", "Commands reach it again"], ground
