"""A mission that would fail, fails on the ground (SPEC §4, issue 59).

Before a submitted mission flies, the ground flies it in fast time against the live
fleet as it is now — each drone where it stands, its battery, sensors, kind and roles,
the ground's fence — with the same plugins (ground/planning.py's prediction, in a
child process), up to `mission.preflight_max_s` simulated seconds. A mission whose
preflight fails is not flown: the API answers 422 with the line, the simulated time and
the cause. One still running at the bound passes: a mission that waits on the world (a
sensor crossing a threshold, a field sensor's alarm) says what it was still waiting
for. `?preflight=false` (`fleet mission submit --no-preflight`) skips it on purpose,
logged with who asked.

A preflight is bounded as a mission is: its child process has the sandbox's memory limit
(`mission.max_memory_mb`) and a wall bound (`mission.preflight_wall_s`); at the bound a
script computing at its own line is refused naming the line, one whose simulation was
still flying passes, judged as far as it got. Up to `mission.preflight_concurrency`
preflights run side by side; one more is answered 503 with Retry-After, never queued.

What a preflight cannot see: the radio (links are not simulated), other missions'
drones (a drone another mission holds is free in the copy), and wind, GPS or an
autopilot that refuses what the simulator accepts.
"""

from __future__ import annotations

import msgspec

from dronefleet.ground.planner import Planner, live_world_of, plugins_dir
from dronefleet.ground.planning import DUMP_WAIT_S, Bounds, Prediction, SimulationBound, predict
from dronefleet.ground.station import GroundStation
from dronefleet.schemas.errors import InvalidMessage


class Preflight(msgspec.Struct, frozen=True, kw_only=True):
    """What the preflight predicted, reported with the submission."""

    passed: bool
    status: str  # the simulated mission's: finished, failed, cancelled
    cause: str | None
    message: str
    line: int | None  # in the script, where it failed
    t_s: float  # simulated seconds from start to end
    wall_s: float  # what it took on the ground's machine
    battery_left: dict[str, float | None]  # per drone the mission used, 0..1
    flying_s: dict[str, float]
    # What the prediction could not know and where the script first read it: a
    # prediction that failed after that line passes (soundness, ADR 0014)
    unknown: str | None = None

    def failure(self) -> str:
        """What a refused submission says (the API's 422, the CLI's error)."""
        where = f" at line {self.line}" if self.line is not None else ""
        return (f"preflight: the mission {self.status} after {self.t_s:g} s simulated{where}: {self.cause} - {self.message} "
                "(not flown; fix it, or submit with --no-preflight / ?preflight=false to fly it anyway)")

    def summary(self) -> str:
        """One line for the mission's log, `fleet mission submit` and `fleet demo`."""
        left = ", ".join(f"{d} {b:.0%}" for d, b in sorted(self.battery_left.items()) if b is not None)
        verdict = "passed" if self.passed else "FAILED"
        text = f"Preflight {verdict}: {self.status} {self.cause or ''} after {self.t_s:g} s simulated ({self.wall_s:.1f} s on the ground)"
        if self.message and self.message != self.cause:
            text += f" - {self.message}"
        if self.unknown is not None:
            text += f"; unknown to it: {self.unknown}"
        return text + (f"; battery left: {left}" if left else "")


def judge(prediction: Prediction) -> Preflight:
    """Passed: the mission finished, or was still running at the bound (it waits on the
    world), or it failed only after reading what the prediction cannot know (its
    world's sensors, field sensors and radio are a copy, not the field's future:
    what followed was a guess); anything else failed, at its line."""
    unknown = prediction.unknown
    read = None if unknown is None else (f"line {unknown.line}: " if unknown.line is not None else "") + unknown.what
    flew = prediction.status == "finished" or prediction.cause == "time_limit"
    passed = flew or read is not None
    message = prediction.message
    if read is not None and not flew:
        message = f"not refused: it {prediction.status} ({prediction.cause}) after reading {read}, which a preflight cannot know - {message}"
    return Preflight(
        passed=passed, status=prediction.status, cause=prediction.cause, message=message,
        line=prediction.line if not passed else None, t_s=prediction.duration_s, wall_s=prediction.wall_s,
        battery_left={d: p.battery_end for d, p in prediction.drones.items()},
        flying_s={d: p.flying_s for d, p in prediction.drones.items()},
        unknown=read,
    )


class PreflightUnavailable(Exception):
    """The preflight could not run (no drone with a position, the simulation overran)."""


class PreflightBusy(Exception):
    """Every preflight slot is taken (`mission.preflight_concurrency`): try again after
    `retry_after_s`, at most one preflight's wall bound."""

    def __init__(self, retry_after_s: float) -> None:
        self.retry_after_s = retry_after_s
        super().__init__(f"every preflight slot is busy; try again in {retry_after_s:g} s")


def bounded(bound: SimulationBound, max_s: float) -> Preflight:
    """The verdict on a simulation its wall bound ended. A script computing at its own line
    then would never give the drones a command again: refused, naming the line and the
    bound. One whose simulation was still flying passes, judged as far as it got."""
    limit = f"the preflight's bound of {bound.wall_s:g} s on the ground (mission.preflight_wall_s)"
    t_s = bound.simulated_s or 0.0
    if bound.line is not None:
        return Preflight(passed=False, status="failed", cause="security", line=bound.line, t_s=t_s, wall_s=bound.wall_s,
                         message=f"line {bound.line}: the script was still computing there, never waiting on a drone, "
                                 f"when {limit} ended it", battery_left={}, flying_s={})
    return Preflight(passed=True, status="running", cause="wall_bound", line=None, t_s=t_s, wall_s=bound.wall_s,
                     message=f"judged up to {t_s:g} s of {max_s:g} s simulated: {limit} came first",
                     battery_left={}, flying_s={})


async def run_preflight(station: GroundStation, planner: Planner, source: str) -> Preflight:
    """Fly `source` in fast time against the live fleet, in one of the planner's slots
    (PreflightBusy if none is free), within the mission sandbox's memory limit and the
    preflight's wall bound."""
    settings = station.config.mission
    try:
        world = live_world_of(station)
    except InvalidMessage as exc:
        raise PreflightUnavailable(exc.reason) from None
    bounds = Bounds(wall_s=settings.preflight_wall_s, memory_mb=settings.max_memory_mb,
                    cpu_s=min(settings.max_cpu_s, settings.preflight_wall_s + 5))
    if not planner.free():
        raise PreflightBusy(settings.preflight_wall_s + DUMP_WAIT_S)
    async with planner.slot():
        try:
            prediction = await predict(source, world, settings.preflight_max_s, plugins_dir(station), bounds)
        except SimulationBound as bound:
            return bounded(bound, settings.preflight_max_s)
        except (TimeoutError, InvalidMessage) as exc:
            raise PreflightUnavailable(str(exc)) from None
    return judge(prediction)
