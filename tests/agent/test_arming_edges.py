"""The agent never misses or misreads an autopilot's state change, whatever its own
timers do (ADR 0018): the command handler against an autopilot that reports arming
and mode only at its heartbeats (tests/agent/heartbeat_autopilot.py), in fast time.

The properties are checked over random interleavings of commands, the autopilot's own
events (a landing's auto-disarm, a failsafe return), heartbeat phases and the phase of
the handler's own timers, against the autopilot's log of what it did and reported."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass, field

import msgspec
from hypothesis import HealthCheck, given, note, settings
from hypothesis import strategies as st

from dronefleet.agent.arming import EFFECT_LAG_S
from dronefleet.agent.handler import CommandHandler, FlightSettings
from dronefleet.agent.priority import INSTANT
from dronefleet.bus.clock import VirtualClock
from dronefleet.schemas import commands as c
from dronefleet.schemas.status import CommandStatus, SystemStatus
from tests.agent.heartbeat_autopilot import HeartbeatAutopilot, Report, north_of_spawn

TERMINAL = frozenset({"finish", "cancel", "failure", "stop"})


@dataclass
class Sent:
    cmd: c.Command
    at_s: float
    accepted: bool
    reason: str | None
    armed_then: bool  # whether the autopilot was armed when the command was decided on


@dataclass
class Rig:
    clock: VirtualClock
    ap: HeartbeatAutopilot
    handler: CommandHandler
    out: list[CommandStatus | SystemStatus]
    sent: list[Sent] = field(default_factory=list)

    def send(self, name: str, **fields: object) -> Sent:
        cmd = msgspec.convert({"cmd": name, "command_id": f"c{len(self.sent)}", "drone_id": "d1", **fields},
                              c.Command)
        armed_then = self.ap.armed
        reply = self.handler.submit(cmd)
        self.sent.append(Sent(cmd, self.clock.monotonic(), reply.accepted, reply.reason, armed_then))
        return self.sent[-1]

    def ms(self, t_s: float) -> int:
        return self.clock.epoch_ms + round(t_s * 1000)

    def states(self, sent: Sent) -> list[str]:
        return [s.state for s in self.out if isinstance(s, CommandStatus) and s.command_id == sent.cmd.command_id]

    def system(self, state: str) -> list[SystemStatus]:
        return [s for s in self.out if isinstance(s, SystemStatus) and s.state == state]

    def report_at(self, t_s: float) -> Report:
        return [r for r in self.ap.reports if r.t <= t_s][-1]

    async def until(self, predicate: object, limit_s: float = 60.0, step_s: float = 0.01) -> None:
        waited = 0.0
        while not predicate():  # type: ignore[operator]
            assert waited < limit_s, f"not within {limit_s} s; statuses {self.out[-6:]}"
            await self.clock.advance(step_s)
            waited += step_s


@asynccontextmanager
async def rig(phase_s: float, handler_after_s: float = 0.0) -> AsyncIterator[Rig]:
    clock = VirtualClock()
    ap = HeartbeatAutopilot(clock, phase_s=phase_s)
    out: list[CommandStatus | SystemStatus] = []
    handler = CommandHandler("d1", ap, FlightSettings(acceptance_radius=1.0), clock, out.append)
    await ap.start()
    await clock.advance(handler_after_s)  # the handler's timers at a phase of their own
    task = asyncio.get_running_loop().create_task(handler.run())
    try:
        yield Rig(clock, ap, handler, out)
    finally:
        task.cancel()
        await ap.close()
        await asyncio.gather(task, return_exceptions=True)


async def test_a_disarm_reported_just_before_an_arm_is_announced_and_ends_nothing_after_it() -> None:
    """The sequence seen on PX4 and `fleet sim`: a landing ends, the autopilot disarms by
    itself 2 s after touchdown, and the operator arms and takes off again as soon as
    telemetry shows it disarmed, with two gotos during the climb. The disarm is
    announced once, before the arm; the takeoff finishes; only the last goto flies."""
    async with rig(phase_s=0.27) as r:
        await r.until(lambda: r.ap.reports)
        assert r.send("arm").accepted
        await r.clock.advance(1.5)
        takeoff = r.send("takeoff", alt=8.0)
        await r.until(lambda: "finish" in r.states(takeoff))
        land = r.send("land")
        await r.until(lambda: "finish" in r.states(land))
        await r.until(lambda: not r.ap.reports[-1].state.armed)  # telemetry shows it disarmed: at once
        arm = r.send("arm")
        takeoff = r.send("takeoff", alt=8.0)
        first = r.send("goto", lat=north_of_spawn(15)[0], lon=north_of_spawn(15)[1])
        last = r.send("goto", lat=north_of_spawn(25)[0], lon=north_of_spawn(25)[1])
        assert all(s.accepted for s in (arm, takeoff, first, last))
        await r.until(lambda: "finish" in r.states(last) or "cancel" in r.states(last), 30)
        disarms = r.system("disarm")
        assert len(disarms) == 1 and disarms[0].timestamp <= r.ms(arm.at_s), r.out
        assert r.states(takeoff) == ["start", "finish"], r.out
        assert r.states(first) == ["queued", "cancel"]
        assert r.states(last) == ["queued", "start", "finish"], r.out


async def test_an_arm_that_found_the_drone_still_armed_does_not_hide_the_auto_disarm_after_it() -> None:
    """An arm sent within the 2 s between touchdown and the landing's auto-disarm changes
    nothing at the autopilot. Its disarm then is the autopilot's own: announced, and a
    takeoff after it is refused `disarmed` rather than accepted on a stale belief."""
    async with rig(phase_s=0.5) as r:
        await r.until(lambda: r.ap.reports)
        r.send("arm")
        await r.clock.advance(1.5)
        takeoff = r.send("takeoff", alt=8.0)
        await r.until(lambda: "finish" in r.states(takeoff))
        land = r.send("land")
        await r.until(lambda: "finish" in r.states(land))
        assert r.ap.armed
        assert r.send("arm").accepted  # still armed: nothing happens at the autopilot
        await r.until(lambda: not r.ap.reports[-1].state.armed, 5)
        assert [d[1] for d in r.ap.disarms] == ["auto"]
        assert len(r.system("disarm")) == 1
        late = r.send("takeoff", alt=8.0)
        assert not late.accepted and late.reason == "disarmed"


# ----- properties over random interleavings -------------------------------------------

ACTIONS = ["arm", "disarm", "takeoff", "goto", "goto", "land", "return", "cancel", "failsafe", "arm_on_disarm"]


@st.composite
def scenarios(draw: st.DrawFn) -> tuple[float, float, list[tuple[float, str]]]:
    phase = draw(st.floats(0, 0.99))
    handler_after = draw(st.floats(0, 0.5))
    steps = draw(st.lists(st.tuples(st.integers(0, 60).map(lambda n: n * 0.05), st.sampled_from(ACTIONS)),
                          min_size=3, max_size=14))
    return phase, handler_after, steps


async def play(r: Rig, steps: list[tuple[float, str]]) -> None:
    for gap_s, action in steps:
        await r.clock.advance(gap_s)
        if action == "failsafe":
            r.ap.failsafe_return()
        elif action == "arm_on_disarm":  # the operator who arms as soon as telemetry shows disarmed
            if r.ap.landed != "on_ground":
                continue
            await r.until(lambda: not r.ap.reports[-1].state.armed, 15, step_s=0.05)
            r.send("arm")
            r.send("takeoff", alt=6.0)
        elif action == "goto":
            r.send("goto", lat=north_of_spawn(10 + gap_s)[0], lon=north_of_spawn(10 + gap_s)[1])
        elif action == "takeoff":
            r.send("takeoff", alt=6.0)
        else:
            r.send(action)
    await r.clock.advance(15.0)  # everything the autopilot does settles (its longest timer: 10 s)


def check_properties(r: Rig) -> None:
    reports = r.ap.reports
    # 1. Every disarm the autopilot reported and did on its own is announced once, when
    #    reported; one the agent asked for is not.
    expected = []
    for before, after in zip(reports, reports[1:], strict=False):
        if before.state.armed and not after.state.armed:
            cause = [why for t, why in r.ap.disarms if t <= after.t][-1]
            if cause == "auto":
                expected.append(r.ms(after.t))
    assert [s.timestamp for s in r.system("disarm")] == expected, (r.ap.disarms, r.out)
    # 2. Every failsafe return the autopilot reported is announced once, when reported.
    returns = [r.ms(after.t) for before, after in zip(reports, reports[1:], strict=False)
               if after.state.flight_mode == "return_to_launch" != before.state.flight_mode
               and not any(s.accepted and s.cmd.name == "return" and after.t - EFFECT_LAG_S < s.at_s <= after.t
                           for s in r.sent)]
    assert [s.timestamp for s in r.system("return")] == returns, r.out
    for sent in r.sent:
        ends = [s for s in r.out if isinstance(s, CommandStatus) and s.command_id == sent.cmd.command_id
                and s.state in TERMINAL]
        # 3. A decision is never taken on a stale armed flag: refused `disarmed` only when
        #    the autopilot is disarmed.
        if not sent.accepted and sent.reason == "disarmed":
            assert not sent.armed_then, f"{sent.cmd.name} refused disarmed at {sent.at_s:.2f} while armed"
        if not sent.accepted:
            continue
        # 4. No command is ended by a state older than its own start: a `disarmed` end
        #    follows a report, sent after the command was accepted, that says disarmed.
        for end in ends:
            if "disarmed" in (end.reason or ""):
                t_end = (end.timestamp - r.clock.epoch_ms) / 1000  # to the ms: a report within it counts
                assert any(sent.at_s <= rep.t <= t_end + 0.001 and not rep.state.armed for rep in reports), \
                    f"{sent.cmd.name} ended {end.reason} at {t_end:.2f} on a state from before {sent.at_s:.2f}"
        # 5. Every accepted command ends: none is left hanging once the autopilot settled.
        if sent.accepted and sent.cmd.name not in INSTANT:
            assert ends, f"{sent.cmd.name} accepted at {sent.at_s:.2f} never ended: {r.states(sent)}"


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios())
def test_arming_and_modes_are_read_from_every_edge(scenario: tuple[float, float, list[tuple[float, str]]]) -> None:
    phase, handler_after, steps = scenario
    note(f"heartbeat phase {phase:.3f} s, handler after {handler_after:.3f} s, steps {steps}")

    async def run() -> None:
        async with rig(phase, handler_after) as r:
            await r.until(lambda: r.ap.reports)
            await play(r, steps)
            note("\n".join(f"{s.at_s:.2f} {s.cmd.name} {'accepted' if s.accepted else s.reason}" for s in r.sent))
            note("\n".join(map(repr, r.out)))
            note("\n".join(f"{rep.t:.2f} {rep.state.armed} {rep.state.flight_mode} {rep.state.landed_state}" for rep in r.ap.reports[:40]))
            check_properties(r)

    asyncio.run(run())
