"""The command handler: validation against the drone's state, priority, execution
through the flight-controller port, and status tracking. Shared by every adapter.

`submit` decides at once (that decision is the queryable's reply) and queues the
accepted command; one worker executes accepted commands in arrival order, so an
`arm` followed at once by a `takeoff` reaches the autopilot in that order. Every
change of the autopilot's connection, arming, mode or landed state reaches `track`
as the adapter receives it (`FlightController.watch`), so no poll's phase can hide
an edge; the tracking loop polls only for goals reached. Arming is one view
(agent/arming.py): the reported edges and the arm or disarm not reported yet.
Statuses go out through the `emit` callback. The invariants are ADR 0018's.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import msgspec
from msgspec import UNSET

from dronefleet.agent.arming import EFFECT_LAG_S, Arming
from dronefleet.agent.fc_port import FcError, FcState, FlightController
from dronefleet.agent.priority import INSTANT, Active, Situation, decide, end_state
from dronefleet.agent.tracker import Goal, finished, interrupted, system_events
from dronefleet.bus.clock import Clock
from dronefleet.schemas import commands as c
from dronefleet.schemas.commands import Command, CommandReply
from dronefleet.schemas.fence import Geofence, refusal
from dronefleet.schemas.geo import bearing_deg, normalize_deg, offset_body
from dronefleet.schemas.status import DISARMED, FAILSAFE_ID_PREFIX, FAILSAFE_REASON, CommandStatus, Coords, SystemStatus

log = logging.getLogger(__name__)

POLL_S = 0.05
IDLE_POLL_S = 0.5  # with no command running there is no goal to watch: edges come through `watch`
REPLIES_REMEMBERED = 64  # command ids answered (a retry of one is not run twice)
RETURN_MIN_ALT_M = 10.0
NEEDS_POSITION = frozenset({"goto", "move", "turn"})
ENDS_DISARMED = frozenset({"land", "return"})  # a disarm on the ground is how these end, not an interruption


@dataclass(frozen=True)
class FlightSettings:
    acceptance_radius: float = 0.5
    takeoff_altitude: float = 15.0
    return_altitude: float = 15.0
    max_speed: float = 5.0
    geofence: Geofence = field(default_factory=Geofence)


@dataclass(eq=False)
class _Job:
    cmd: Command
    seen: FcState  # the autopilot's state when the command was accepted
    accepted_s: float  # when (the handler's clock)
    goal: Goal | None = None
    started: bool = False
    ended: bool = False

    @property
    def name(self) -> str:
        return self.cmd.name

    @property
    def active(self) -> Active:
        return Active(self.cmd.name, self.cmd.command_id)


class CommandHandler:
    def __init__(
        self,
        drone_id: str,
        fc: FlightController,
        settings: FlightSettings,
        clock: Clock,
        emit: Callable[[CommandStatus | SystemStatus], None],
    ) -> None:
        self.drone_id = drone_id
        self._fc = fc
        self._settings = settings
        self._clock = clock
        self._emit = emit
        self._running: _Job | None = None
        self._queued: _Job | None = None
        self._work: asyncio.Queue[_Job] = asyncio.Queue()
        self._accepted_at: dict[str, float] = {}
        self._replies: dict[str, CommandReply] = {}  # command id → the answer given, oldest first
        self._arming = Arming()
        self._prev = FcState()
        fc.watch(self.track)

    @property
    def running(self) -> str | None:
        """The name of the command running now, if any."""
        return self._running.name if self._running is not None and not self._running.ended else None

    @property
    def connected(self) -> bool:
        return self._fc.state().connected

    # ----- decisions (synchronous: this is the queryable's answer) -------------------

    def submit(self, cmd: Command) -> CommandReply:
        """Decide on a command; a command id seen before gets the same answer again and
        nothing else happens (a sender whose reply was lost on the radio may retry)."""
        if cmd.command_id and cmd.command_id in self._replies:
            log.info("%s: %s %s again: answered as before", self.drone_id, cmd.name, cmd.command_id)
            return self._replies[cmd.command_id]
        reply = self._decide(cmd)
        if cmd.command_id:
            self._replies[cmd.command_id] = reply
            while len(self._replies) > REPLIES_REMEMBERED:
                del self._replies[next(iter(self._replies))]
        return reply

    def _decide(self, cmd: Command) -> CommandReply:
        name, now = cmd.name, self._clock.monotonic()
        state = self._fc.state()
        reason: str | None = None
        if not state.connected:
            reason = "flight controller disconnected"
        elif name in NEEDS_POSITION and state.position is None:
            reason = "no position yet"
        else:  # whatever path the command came by (SPEC §11)
            reason = refusal(self._settings.geofence, cmd, state.position, state.heading, self._settings.takeoff_altitude)
        if reason is None:
            armed = self._arming.armed(now)
            decision = decide(name, Situation(armed, self._active(self._running), self._active(self._queued)))
            reason = decision.reason
        if reason is not None:
            self._status(cmd, "failure", reason=reason)
            log.info("%s refused %s: %s", self.drone_id, name, reason)
            return CommandReply(command_id=cmd.command_id, accepted=False, reason=reason)

        for ended in decision.ends:
            job = self._job_of(ended)
            if job is not None:
                by = f"{FAILSAFE_REASON}: " if cmd.command_id.startswith(FAILSAFE_ID_PREFIX) else ""
                self._end(job, end_state(job.name), f"{by}superseded by {name}")
        job = _Job(cmd, seen=state, accepted_s=now)
        self._accepted_at[name] = now
        if name in ("arm", "disarm"):
            self._arming.requested(cmd.command_id, name == "arm", now)
        if decision.verdict == "queue":
            self._queued = job
            self._status(cmd, "queued", **self._queued_target(cmd, state))
        else:
            if name not in INSTANT:
                self._running = job
            self._work.put_nowait(job)
        return CommandReply(command_id=cmd.command_id, accepted=True)

    @staticmethod
    def _active(job: _Job | None) -> Active | None:
        return job.active if job is not None else None

    def _job_of(self, active: Active) -> _Job | None:
        for job in (self._running, self._queued):
            if job is not None and job.active == active:
                return job
        return None

    # ----- execution ---------------------------------------------------------------

    async def run(self) -> None:
        """Execute accepted commands and track them until cancelled."""
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._execute_loop(), name=f"{self.drone_id} command worker")
            tg.create_task(self._track_loop(), name=f"{self.drone_id} status tracker")

    async def _execute_loop(self) -> None:
        while True:
            job = await self._work.get()
            if job.ended:
                continue
            try:
                await self._execute(job)
            except FcError as exc:
                self._fail(job, str(exc) or type(exc).__name__)

    async def _execute(self, job: _Job) -> None:
        cmd, fc, s = job.cmd, self._fc, self._fc.state()
        st = self._settings
        extra: dict[str, object] = {}
        match cmd:
            case c.Arm():
                await fc.arm()
                self._arming.acknowledged(cmd.command_id, self._clock.monotonic())
            case c.Disarm():
                await fc.disarm()
                self._arming.acknowledged(cmd.command_id, self._clock.monotonic())
            case c.Takeoff():
                alt = cmd.alt if cmd.alt is not None else st.takeoff_altitude
                job.goal, extra = Goal("altitude", rel_alt=alt), {"altitude": alt}
                await fc.takeoff(alt)
            case c.Land():
                job.goal = Goal("landed")
                await fc.land()
            case c.Return():
                alt = max(cmd.alt if cmd.alt is not None else st.return_altitude, RETURN_MIN_ALT_M)
                job.goal, extra = Goal("landed"), {"altitude": alt}
                await fc.return_to_launch(alt)
            case c.Goto() | c.Move():
                lat, lon, alt, yaw, speed = self._goto_target(cmd, s)
                job.goal = Goal("position", lat=lat, lon=lon, alt=alt)
                extra = {"coords": Coords(lat=lat, lon=lon, alt=alt)}
                await fc.goto(lat, lon, alt, yaw, speed)
            case c.Turn():
                assert s.position is not None
                heading = normalize_deg(s.heading + cmd.deg)
                job.goal = Goal("heading", heading=heading)
                await fc.goto(s.position.lat, s.position.lon, s.position.alt, heading, None)
            case c.Cancel():
                await fc.hold()
            case c.StartOffboard():
                if s.flight_mode != "offboard":
                    # Autopilots switch only while setpoints stream: hover in place.
                    await fc.set_setpoint("velocity_ned", {"north": 0.0, "east": 0.0, "down": 0.0, "yaw": s.heading})
                    await fc.start_offboard()
            case c.StopOffboard():
                await fc.stop_offboard()
            case c.PositionNed() | c.VelocityNed() | c.VelocityBody() | c.Attitude() | c.AttitudeRate():
                values = {k: v for k, v in msgspec.structs.asdict(cmd).items() if k not in c.COMMON_FIELDS}
                if cmd.name in ("position_ned", "velocity_ned") and values.get("yaw") is None:
                    values["yaw"] = s.heading
                if isinstance(cmd, c.PositionNed):
                    job.goal = Goal("local", ned=(cmd.north, cmd.east, cmd.down))
                await fc.set_setpoint(cmd.name, values)
                if s.flight_mode != "offboard":
                    await fc.start_offboard()
        if job.ended:  # superseded while the autopilot was answering
            return
        if job.name in INSTANT:
            self._status(cmd, "success")
        else:
            job.started = True
            self._status(cmd, "start", **extra)
            # What changed while the autopilot was answering applies to it from the start.
            self._check(job, job.seen, self._fc.state())

    def _queued_target(self, cmd: Command, s: FcState) -> dict[str, object]:
        """Where a goto queued behind a takeoff will fly, as far as known now: with no
        alt it keeps the altitude the takeoff reaches. (A move depends on where the
        takeoff ends, so its target is told only when it starts.)"""
        if not isinstance(cmd, c.Goto) or s.position is None:
            return {}
        alt = cmd.alt
        if alt is None:
            goal = self._running.goal if self._running is not None else None
            climbing = goal is not None and goal.kind == "altitude" and s.home is not None
            alt = s.home.alt + goal.rel_alt if climbing else s.position.alt  # type: ignore[union-attr]
        return {"coords": Coords(lat=cmd.lat, lon=cmd.lon, alt=alt)}

    def _goto_target(
        self, cmd: c.Goto | c.Move, s: FcState
    ) -> tuple[float, float, float, float | None, float]:
        """Absolute target of a goto or move: lat, lon, alt AMSL, yaw (deg), speed."""
        assert s.position is not None
        pos = s.position
        speed = cmd.speed if cmd.speed is not None else self._settings.max_speed
        if isinstance(cmd, c.Move):
            lat, lon = offset_body(pos.lat, pos.lon, s.heading, cmd.x, cmd.y)
            return lat, lon, pos.alt + cmd.z, s.heading, speed
        alt = cmd.alt if cmd.alt is not None else pos.alt
        if cmd.yaw is UNSET:
            yaw: float | None = s.heading
        elif cmd.yaw is None:
            yaw = bearing_deg(pos.lat, pos.lon, cmd.lat, cmd.lon)
        else:
            yaw = normalize_deg(cmd.yaw)
        return cmd.lat, cmd.lon, alt, yaw, speed

    # ----- tracking -----------------------------------------------------------------

    async def _track_loop(self) -> None:
        while True:
            self.track(self._fc.state())
            await self._clock.sleep(POLL_S if self._running is not None else IDLE_POLL_S)

    def track(self, s: FcState) -> None:
        """One snapshot of the autopilot: every edge the adapter reports comes here, in
        order, and the tracking loop's polls besides."""
        prev, self._prev = self._prev, s
        now = self._clock.monotonic()
        recent = frozenset(n for n, t in self._accepted_at.items() if now - t < EFFECT_LAG_S)
        edge = self._arming.report(s.armed, now) if s.connected else None
        for event in system_events(prev, s, recent, disarmed_alone=edge == "unrequested" and not s.armed):
            self._emit(SystemStatus(drone_id=self.drone_id, timestamp=self._clock.time_ms(), component="system", state=event))  # type: ignore[arg-type]
            log.info("%s system %s", self.drone_id, event)
        job = self._running
        if job is not None and job.started and not job.ended:
            self._check(job, prev, s, disarm_edge=edge is not None and not s.armed)

    def _check(self, job: _Job, prev: FcState, s: FcState, disarm_edge: bool = False) -> None:
        """End the running job if the autopilot left it between `prev` and `s`, or
        finish it if `s` reached its goal. A disarm ends it on its edge (reported after
        the job began), or once no arm is expected and the job is old enough that the
        report read is newer than the job (a heartbeat comes within EFFECT_LAG_S)."""
        if not s.connected:
            return
        now = self._clock.monotonic()
        reason = interrupted(job.name, prev, s)
        if (reason is None and job.name not in ENDS_DISARMED and not self._arming.armed(now)
                and (disarm_edge or now - job.accepted_s >= EFFECT_LAG_S)):
            reason = DISARMED
        if reason is not None:
            self._end(job, end_state(job.name), reason)
        elif job.goal is not None and finished(job.goal, s, self._settings.acceptance_radius):
            job.ended = True
            self._running = None
            self._status(job.cmd, "finish")
            if job.name == "takeoff" and self._queued is not None:
                queued, self._queued = self._queued, None
                self._running = queued
                self._work.put_nowait(queued)

    # ----- endings ------------------------------------------------------------------

    def _end(self, job: _Job, state: str, reason: str) -> None:
        job.ended = True
        if job is self._running:
            self._running = None
            if job.name == "takeoff" and self._queued is not None:
                self._end(self._queued, "cancel", f"takeoff ended: {reason}")
        if job is self._queued:
            self._queued = None
        self._status(job.cmd, state, reason=reason)

    def _fail(self, job: _Job, reason: str) -> None:
        log.warning("%s %s failed: %s", self.drone_id, job.name, reason)
        if job.name in ("arm", "disarm"):
            self._arming.refused(job.cmd.command_id)
        if job is self._running:
            self._end(job, "failure", reason)
        else:
            job.ended = True
            self._status(job.cmd, "failure", reason=reason)

    def _status(self, cmd: Command, state: str, **extra: object) -> None:
        self._emit(
            CommandStatus(
                drone_id=self.drone_id,
                timestamp=self._clock.time_ms(),
                command_id=cmd.command_id,
                command=cmd.name,
                state=state,  # type: ignore[arg-type]
                **extra,  # type: ignore[arg-type]
            )
        )


