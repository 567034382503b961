"""One running mission: its script and subroutines, its drones, its end.

A Mission lives on the ground's event loop next to the GroundStation. It hears every
station event (telemetry, statuses, drone changes, sensor readings) synchronously,
wakes the verbs waiting on them, and ends itself when one of its drones turns manual,
errs, times out, loses a sensor it was assigned for, or starts an automatic return.
The first end wins: it records status and cause (thesis tables 5.2/5.3), stops every
subroutine (within a second even for a script spinning without verbs), leaves flying
drones holding (or returning, by config), sends drones at critical battery home, and
releases all of them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import msgspec

from bus.clock import Clock
from bus.port import Unreachable
from mission import assignment as a
from mission.plugins import MissionPlugins, PluginLibrary
from mission.port import FleetPort, MissionConfig
from mission.runtime import Scheduler, Stopped, Subroutine, current_subroutine
from mission.sandbox import Guards, SecurityViolation
from schemas.bundles import BUNDLE_ENDS, BundleRecord, BundleStatus, new_bundle_id
from schemas.errors import STATE_UNKNOWN, CommandRejected, FleetError, InvalidMessage
from schemas.fence import CONFLICT
from schemas.fence import REASON as FENCE
from schemas.fleet import CRITICAL_BATTERY, DroneInfo, WatchEvent
from schemas.status import GEOFENCE_OUTSIDE, TERMINAL_STATES, CommandStatus, SystemStatus, ended_by_failsafe
from schemas.telemetry import Telemetry

if TYPE_CHECKING:
    from mission.dsl import Drone

log = logging.getLogger(__name__)

MissionStatus = Literal["pending", "running", "finished", "failed", "cancelled"]
# Thesis table 5.3, plus geofence, link_lost, ground_restart (SPEC §5) and time_limit.
CAUSES: dict[str, tuple[MissionStatus, str]] = {
    "success": ("finished", "success"),
    "user": ("cancelled", "user request"),
    "manual": ("cancelled", "manual mode activated"),
    "return": ("cancelled", "automatic return to launch detected"),
    "requirements": ("failed", "not enough drones to fulfill mission requirements"),
    "cmd_exec": ("failed", "failure in command execution"),
    "cmd_parse": ("failed", "failure in command parsing"),
    "plugin_error": ("failed", "plugin encountered an error"),
    "plugin_param": ("failed", "illegal or missing plugin input parameter"),
    "plugin_missing": ("failed", "plugin is not loaded"),
    "plugin_disabled": ("failed", "plugin is not enabled"),
    "timeout": ("failed", "drone timeout"),
    "sensor": ("failed", "sensor timeout"),
    "script": ("failed", "malformed script"),
    "revoked": ("failed", "referenced revoked drone"),
    "drone_error": ("failed", "drone entered error state"),
    "security": ("failed", "mission script called a blacklisted method or import"),
    "irreplaceable": ("failed", "requested replacement of drone that can not be replaced"),
    "unexpected": ("failed", "unexpected exception"),
    "geofence": ("failed", "drone left the geofence"),
    "link_lost": ("failed", "lost the link to a drone"),
    "ground_restart": ("failed", "the ground station stopped while the mission ran"),
    "time_limit": ("cancelled", "time limit reached"),  # fast-time simulation's --max-time
}
T = TypeVar("T")
BUNDLE_NO_TIMEOUT_S = 3600.0  # a bundle without timeout_s: how long the mission expects it may run alone


@dataclass
class _PendingBundle:
    drone_id: str
    bundle_id: str
    deadline: float  # clock.monotonic() by which the bundle should have ended
    done: asyncio.Future[BundleRecord]


CLAIM_TRIES = 3  # picks of free drones when another mission claims one first
DELIVERY_TRIES = 3  # a command with no answer is sent this many times in all
# Commands with an absolute goal, sent again when the drone's lost-link failsafe ended
# them (relative ones — move by offsets, turn, offboard — would not mean the same again).
RESUMABLE = frozenset({"takeoff", "goto", "return", "land"})
RESUME_TRIES = 3
INSTANT_COMMANDS = frozenset({"arm", "disarm", "cancel"})
HOMEWARD = frozenset({"return", "land"})  # left running when a mission ends
STOP_GRACE_S = 1.0
FREE_STATES = frozenset({"ready", "hold"})


class MissionRecord(msgspec.Struct, kw_only=True):
    """SPEC §4 / thesis table 5.1."""

    mission_id: str
    name: str = ""
    status: MissionStatus = "pending"
    cause: str | None = None
    message: str | None = None
    start: int | None = None  # ms since the epoch
    end: int | None = None
    plugins: list[str] = msgspec.field(default_factory=list)
    active_drones: list[str] = msgspec.field(default_factory=list)
    used_drones: list[str] = msgspec.field(default_factory=list)
    submitted_by: str | None = None  # the API token's holder (SPEC §9), when tokens are on


class MissionLogLine(msgspec.Struct, frozen=True, kw_only=True):
    timestamp: int
    level: Literal["info", "warn", "error"]
    message: str


class CommandResult(msgspec.Struct, frozen=True, kw_only=True):
    """What one verb sent and how it ended, for the simulation result."""

    drone_id: str
    cmd: str
    t_sent_ms: int
    t_end_ms: int
    state: str
    target: dict[str, float] | None = None


class MissionOver(FleetError):
    """Internal: a verb found the mission failing; its subroutine unwinds."""


class Mission:
    def __init__(
        self,
        record: MissionRecord,
        code: Any,
        station: FleetPort,
        clock: Clock,
        *,
        deterministic: bool = False,
        seed: int | None = None,
        on_change: Callable[[Mission], None] = lambda m: None,
        on_log: Callable[[Mission, MissionLogLine], None] = lambda m, line: None,
        plugins: PluginLibrary | None = None,
        enable: dict[str, dict[str, Any]] | None = None,
    ) -> None:
        self.record = record
        self.code = code
        self.station = station
        self.config: MissionConfig = station.config
        self.clock = clock
        self.deterministic = deterministic
        self.seed = seed
        self._on_change = on_change
        self._on_log = on_log
        self.scheduler: Scheduler | None = None
        self.requests: dict[str, a.Request] = {}  # drone id → how it was assigned
        self.commands: list[CommandResult] = []
        self._pending: dict[str, asyncio.Future[CommandStatus]] = {}  # command id → its terminal status
        self._bundles: dict[str, _PendingBundle] = {}  # bundle id → the push waiting for it
        self._pushed = 0
        self._pulses: dict[str, list[asyncio.Future[None]]] = {}
        self._ended = asyncio.Event()
        self._stop_listening: Callable[[], None] | None = None
        self._critical: set[str] = set()
        self._link_waits: dict[str, asyncio.Task[None]] = {}  # drone id → its link-grace timer
        self._link_back_at: dict[str, asyncio.Future[None]] = {}  # resolved when a lost drone is back
        self._wrappers: list[Drone] = []
        self.plugins = MissionPlugins(self, plugins)
        self._enable_first = enable or {}

    @property
    def id(self) -> str:
        return self.record.mission_id

    @property
    def ending(self) -> bool:
        return self.record.cause is not None

    # ---- log and record -----------------------------------------------------------

    def log(self, level: Literal["info", "warn", "error"], message: str) -> None:
        self._on_log(self, MissionLogLine(timestamp=self.clock.time_ms(), level=level, message=message))

    def changed(self) -> None:
        self.record.active_drones = sorted(self.requests)
        self._on_change(self)

    # ---- life cycle ---------------------------------------------------------------

    async def run(self) -> MissionRecord:
        """Run the script to its end (or the mission's), then clean up. Never raises."""
        from mission.dsl import build_namespace

        self.record.status = "running"
        self.record.start = self.clock.time_ms()
        self.changed()
        self.log("info", "Mission started")
        self._stop_listening = self.station.listen(self._on_event)
        self.scheduler = Scheduler(self._on_error, deterministic=self.deterministic)
        guards = Guards(self.scheduler.tick, lambda text: self.log("info", text), self.seed)
        namespace = build_namespace(self, guards)
        try:
            self.scheduler.spawn(self._main, namespace, name="main")
            idle = asyncio.ensure_future(self.scheduler.wait_idle())
            ended = asyncio.ensure_future(self._ended.wait())
            try:
                await asyncio.wait([idle, ended], return_when=asyncio.FIRST_COMPLETED)
            finally:
                idle.cancel()
                ended.cancel()
            if not self.ending:
                self.end("success")
            await self._wind_down()
        except asyncio.CancelledError:  # the ground is stopping
            if not self.ending:
                self.end("ground_restart")
            await asyncio.shield(self._wind_down())
            raise
        except Exception as exc:  # noqa: BLE001 - a bug here must still end the mission
            log.exception("mission %s: runtime failure", self.id)
            if not self.ending:
                self.end("unexpected", f"{type(exc).__name__}: {exc}")
            await self._wind_down()
        return self.record

    def _main(self, namespace: dict[str, Any]) -> None:
        for plugin_id, inputs in self._enable_first.items():
            namespace["enable"](plugin_id, **inputs)
        exec(self.code, namespace)  # noqa: S102 - compiled by the sandbox

    def end(self, cause: str, message: str | None = None) -> bool:
        """Conclude the mission with `cause` (the first call wins); True if this one did."""
        if self.ending:
            return False
        self.log(*mark_ended(self.record, cause, message))
        if self.scheduler is not None:
            self.scheduler.stop_all()
        self._ended.set()
        return True

    def fail(self, cause: str, message: str) -> MissionOver:
        """End with `cause` and return the exception the calling verb raises."""
        self.end(cause, message)
        return MissionOver(message)

    def setback(self, cause: str, message: str) -> MissionOver:
        """A command refused or failed, or no drone to assign: the mission's failure with
        `cause` - unless a monitoring plugin's subroutine sent it. Then it is the
        plugin's problem (SPEC §5: monitoring plugins log and go on): logged, and only
        that subroutine unwinds; the plugin sees the drone's state next time round."""
        sub = current_subroutine()
        if sub is None or sub.plugin is None or self.ending:
            return self.fail(cause, message)
        self.log("warn", f"plugin {sub.plugin}: {message}; the plugin goes on")
        return MissionOver(message)

    async def _wind_down(self) -> None:
        assert self.scheduler is not None
        self.scheduler.stop_all()
        if not await self.scheduler.join_all(STOP_GRACE_S):
            self.log("error", "a subroutine did not stop within 1 s")
        if self._stop_listening is not None:
            self._stop_listening()
        for wait in self._link_waits.values():
            wait.cancel()
        self._link_waits.clear()
        for fut in self._pending.values():
            if not fut.done():
                fut.cancel()
        for pending in self._bundles.values():
            if not pending.done.done():
                pending.done.cancel()
        for drone_id in sorted(self.requests):
            await self._leave(drone_id)
        self.requests.clear()
        self.record.end = self.clock.time_ms()
        self.changed()

    async def _leave(self, drone_id: str) -> None:
        await leave(self.station, self.id, drone_id, critical=drone_id in self._critical, log=self.log)

    # ---- failures from subroutines ------------------------------------------------

    def _on_error(self, sub: Subroutine, exc: BaseException) -> None:
        if isinstance(exc, MissionOver):
            return
        filename, where = script_frame(exc)
        in_plugin = filename.startswith("<plugin") or sub.name.startswith("plugin ")
        prefix = (f"{filename.strip('<>')} " if in_plugin else "") + (f"line {where}: " if where else "")
        if isinstance(exc, SecurityViolation):
            self.end("security", f"{prefix}{exc}")
        elif isinstance(exc, MemoryError):  # a mission's process is limited by mission.max_memory_mb
            self.end("security", f"{prefix}the script ran out of memory (mission.max_memory_mb)")
        elif isinstance(exc, Exception) and in_plugin:
            self.end("plugin_error", f"{prefix}{type(exc).__name__}: {exc} (in {sub.name})")
        elif isinstance(exc, Exception):  # UnitError, NameError, ZeroDivisionError, …
            self.end("script", f"{prefix}{type(exc).__name__}: {exc}" + ("" if sub.name == "main" else f" (in subroutine {sub.name})"))
        else:
            self.end("unexpected", f"{prefix}{type(exc).__name__}: {exc}")

    # ---- events from the station --------------------------------------------------

    def _on_event(self, event: WatchEvent) -> None:
        data = event.data
        if event.kind == "telemetry":
            self._on_telemetry(data)
        elif event.kind == "status":
            if isinstance(data, CommandStatus):
                self._on_command_status(data)
            elif isinstance(data, BundleStatus):
                self._on_bundle_status(data)
            elif isinstance(data, SystemStatus) and data.drone_id in self.requests:
                self._on_system_status(data)
        elif event.kind == "drone" and data.drone_id in self.requests:
            self._on_drone(data)

    def _on_telemetry(self, telem: Telemetry) -> None:
        waiters = self._pulses.pop(telem.drone_id, None)
        for fut in waiters or ():
            if not fut.done():
                fut.set_result(None)

    def _on_command_status(self, status: CommandStatus) -> None:
        fut = self._pending.get(status.command_id)
        if fut is not None and status.state in TERMINAL_STATES and not fut.done():
            fut.set_result(status)

    def _on_bundle_status(self, status: BundleStatus) -> None:
        pending = self._bundles.get(status.bundle_id)
        if pending is not None and status.ends_bundle:
            self._catch_up(pending, status)

    def _catch_up(self, pending: _PendingBundle, status: BundleStatus | None = None) -> None:
        """Ask the agent for the bundle's record (its whole history); resolve the push
        if the bundle has ended. Statuses sent while the link was down never arrived."""
        async def ask() -> None:
            try:
                record = await self.station.bundle_record(pending.drone_id, pending.bundle_id)
            except (CommandRejected, Unreachable) as exc:
                if status is None:
                    self.log("warn", f"{pending.drone_id}: could not read bundle {pending.bundle_id} yet: {exc}")
                    return
                record = BundleRecord(  # the end was heard; only its history is missing
                    bundle_id=status.bundle_id, state=BUNDLE_ENDS[status.state], step=status.step,
                    steps=status.steps or 0, ended_by=status.reason if status.state == "guard" else None,
                    reason=status.reason if status.state in ("failure", "cancel") else None,
                )
            if record.finished and not pending.done.done():
                pending.done.set_result(record)

        asyncio.get_running_loop().create_task(ask(), name=f"mission {self.id} bundle {pending.bundle_id}")

    def _on_system_status(self, status: SystemStatus) -> None:
        reason = status.reason or ""
        if status.state == "failsafe" and GEOFENCE_OUTSIDE in reason:
            self.end("geofence", f"{status.drone_id} was found {reason.removeprefix('return: ')}; it returns")
        elif status.state == "return":
            self.end("return", f"{status.drone_id} started an automatic return to launch" + (f": {status.reason}" if status.reason else ""))
        elif status.state == "start_manual":
            self.end("manual", f"{status.drone_id} is under manual control")

    def _on_drone(self, info: DroneInfo) -> None:
        if info.state == "unknown":
            self._link_lost(info.drone_id)
            return
        self._link_back(info.drone_id)
        if info.state == "manual":
            self.end("manual", f"{info.drone_id} is under manual control")
        elif info.state == "error":
            if CRITICAL_BATTERY in info.errors:
                self._critical.add(info.drone_id)
            self.end("drone_error", f"{info.drone_id}: {'; '.join(info.errors)}")
        else:
            request = self.requests.get(info.drone_id)
            if isinstance(request, a.BySensors):
                missing = sorted(request.sensors - set(info.sensors))
                if missing:
                    self.end("sensor", f"{info.drone_id} lost its {', '.join(missing)} sensor")

    def _link_lost(self, drone_id: str) -> None:
        """A drone out of reach is not yet a failure: it may be flying back into range
        (or finishing work alone). Wait `mission.link_grace_s` for it."""
        if drone_id in self._link_waits or self.ending:
            return
        grace = self.config.mission.link_grace_s
        alone = [b for b in self._bundles.values() if b.drone_id == drone_id]
        if alone:  # working alone is not a failure: the grace counts from the bundle's end
            ends_in = max(0.0, max(b.deadline for b in alone) - self.clock.monotonic())
            self.log("info", f"{drone_id}: link lost while it runs bundle {alone[0].bundle_id}; waiting up to "
                             f"{ends_in + grace:.0f} s (its timeout, then mission.link_grace_s)")
            grace += ends_in
        else:
            self.log("warn", f"{drone_id}: link lost; waiting up to {grace:g} s for it to come back")
        self._link_back_at.setdefault(drone_id, asyncio.get_running_loop().create_future())
        self._link_waits[drone_id] = asyncio.get_running_loop().create_task(
            self._link_grace(drone_id, grace), name=f"mission {self.id} link grace {drone_id}",
        )

    async def _link_grace(self, drone_id: str, grace_s: float) -> None:
        await self.clock.sleep(grace_s)
        self._link_waits.pop(drone_id, None)
        self.end("link_lost", f"{drone_id} unreachable for {grace_s:g} s (mission.link_grace_s)")

    def _link_back(self, drone_id: str) -> None:
        back = self._link_back_at.pop(drone_id, None)
        if back is not None and not back.done():
            back.set_result(None)
        wait = self._link_waits.pop(drone_id, None)
        if wait is not None:
            wait.cancel()
            self.log("info", f"{drone_id}: link restored, the mission goes on")
            for pending in list(self._bundles.values()):
                if pending.drone_id == drone_id:
                    self._catch_up(pending)

    # ---- what verbs call (on the loop) ----------------------------------------------

    def check_assigned(self, drone_id: str) -> None:
        if drone_id not in self.requests:
            raise self.fail("revoked", f"{drone_id} is not assigned to this mission (revoked or replaced)")

    def free_candidates(self, exclude: str | None = None) -> list[a.Candidate]:
        registry = self.station.registry
        relays = registry.relays
        out = []
        for drone_id in registry.ids():
            info = registry.info(drone_id)
            if info.mission is not None or info.state not in FREE_STATES or drone_id == exclude:
                continue
            t = registry.telemetry(drone_id)
            out.append(a.Candidate(
                drone_id=drone_id,
                sensors=frozenset(info.sensors),
                battery=t.battery.remaining_percent if t.battery else 0.0,
                lat=t.position.lat if t.position else None,
                lon=t.position.lon if t.position else None,
                relay=relays is None or drone_id in relays,
            ))
        return out

    async def assign(self, requests: list[a.Request]) -> list[str]:
        """Pick free drones for `requests` and claim them at the ground. A mission in
        its own process picks from its copy of the registry; should another mission
        have claimed one of them meanwhile, the ground refuses and it picks again."""
        for attempt in range(1, CLAIM_TRIES + 1):
            if self.ending:
                raise MissionOver(self.record.message or "")
            try:
                ids = a.assign_many(requests, self.free_candidates())
            except a.Unfulfilled as exc:
                raise self.setback("requirements", str(exc)) from None
            taken: list[str] = []
            try:
                for drone_id, request in zip(ids, requests, strict=True):
                    await self.take(drone_id, request)
                    taken.append(drone_id)
                return ids
            except CommandRejected as exc:
                for drone_id in taken:
                    del self.requests[drone_id]
                    self.station.release(drone_id)
                self.changed()
                if attempt == CLAIM_TRIES:
                    raise self.setback("requirements", f"could not claim drones: {exc.reason}") from None
                self.log("info", f"{exc.reason}; choosing again")
        raise AssertionError("unreachable")

    async def take(self, drone_id: str, request: a.Request) -> None:
        """Claim one drone; raises CommandRejected if another mission holds it."""
        await self.station.assign(drone_id, self.id)
        self.requests[drone_id] = request
        if drone_id not in self.record.used_drones:
            self.record.used_drones.append(drone_id)
        self.log("info", f"Assigned {drone_id} ({a.describe(request)})")
        self.changed()

    def add_wrapper(self, wrapper: Drone) -> None:
        """A drone newly assigned by the script: plugins start monitoring it."""
        self._wrappers.append(wrapper)
        self.plugins.drone_added(wrapper)

    def drop_wrapper(self, wrapper: Drone) -> None:
        """A drone the script revoked: its monitors stop."""
        if wrapper in self._wrappers:
            self._wrappers.remove(wrapper)
        self.plugins.drone_removed(wrapper)

    def wrappers(self) -> list[Drone]:
        return [w for w in self._wrappers if w.id in self.requests]

    def revoke(self, drone_id: str) -> None:
        self.check_assigned(drone_id)
        del self.requests[drone_id]
        self.station.release(drone_id)
        self.log("info", f"Revoked {drone_id}")
        self.changed()

    def replacement_for(self, drone_id: str) -> str:
        self.check_assigned(drone_id)
        request = self.requests[drone_id]
        if not a.replaceable(request):
            raise self.fail("irreplaceable", f"{drone_id} was assigned as {a.describe(request)} and cannot be replaced")
        t = self.station.registry.telemetry(drone_id)
        if t.position is None:
            raise self.fail("requirements", f"{drone_id} reports no position to find a replacement near")
        new_id = a.replacement(t.position.lat, t.position.lon, self.free_candidates(exclude=drone_id))
        if new_id is None:
            raise self.fail("requirements", f"no free drone can replace {drone_id}")
        return new_id

    async def next_telemetry(self, drone_id: str) -> None:
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._pulses.setdefault(drone_id, []).append(fut)
        await fut

    async def execute(self, drone_id: str, body: dict[str, Any], *, wait: bool = True,
                      wait_clear: bool = False) -> CommandStatus | None:
        """Send one command as this mission; with `wait`, return its terminal status.

        Failures end the mission: the ground's 400 → cmd_parse, a refusal, a failure
        status or no answer → cmd_exec, anything else → unexpected.
        """
        name = str(body["cmd"])
        for interrupted in range(RESUME_TRIES + 1):
            status = await self._execute_once(drone_id, name, body, wait=wait, wait_clear=wait_clear)
            if status is None or not ended_by_failsafe(status) or name not in RESUMABLE:
                break
            if interrupted == RESUME_TRIES:
                self.log("warn", f"{drone_id}: {name} interrupted by its lost-link failsafe {RESUME_TRIES + 1} times; "
                                 "going on without it")
                break
            # The drone held (or turned home) on its own while out of reach; the script
            # still wants this done, so it is sent again once the drone can hear it.
            self.log("warn", f"{drone_id}: {name} was interrupted by the drone's lost-link failsafe; sending it again")
        return status

    async def _execute_once(self, drone_id: str, name: str, body: dict[str, Any], *, wait: bool,
                            wait_clear: bool) -> CommandStatus | None:
        self.check_assigned(drone_id)
        if self._out_of_reach(drone_id):  # the ground would refuse it (unknown)
            await self._heard_again(drone_id, name)
        command_id = self.station.new_command_id()
        fut: asyncio.Future[CommandStatus] = asyncio.get_running_loop().create_future()
        if wait:
            self._pending[command_id] = fut
        sent = self.clock.time_ms()
        try:
            with self._sending(name, drone_id):
                await self._deliver(drone_id, name, json.dumps({**body, "command_id": command_id}).encode(), wait_clear)
                if not wait:
                    return None
                status = await self._outcome(fut, drone_id)
        except (asyncio.CancelledError, MissionOver):
            raise
        except Exception as exc:  # noqa: BLE001
            log.exception("mission %s: %s %s", self.id, name, drone_id)
            raise self.fail("unexpected", f"{name} {drone_id}: {type(exc).__name__}: {exc}") from None
        finally:
            self._pending.pop(command_id, None)
        target: dict[str, float] | None = {k: float(body[k]) for k in ("lat", "lon", "alt") if k in body} or None
        self.commands.append(CommandResult(
            drone_id=drone_id, cmd=name, t_sent_ms=sent, t_end_ms=self.clock.time_ms(), state=status.state, target=target,
        ))
        if status.state == "failure":
            raise self.setback("cmd_exec", f"{name} {drone_id} failed: {status.reason or 'no reason given'}")
        return status

    async def _deliver(self, drone_id: str, name: str, payload: bytes, wait_clear: bool = False) -> None:
        """Send a command; with no answer, send it again (same command id: the agent
        runs it once) before the mission gives up on the drone. With `wait_clear`, a
        target another drone holds (409 conflict) is tried again each time that drone
        reports, for up to mission.clear_wait_s."""
        attempt, waited_for = 1, None
        give_up = self.clock.monotonic() + self.config.mission.clear_wait_s
        while True:
            try:
                await self.station.command(drone_id, payload, self.id)
                if waited_for is not None:
                    self.log("info", f"{drone_id}: {waited_for} cleared the spot, {name} goes")
                return
            except Unreachable:
                if self._out_of_reach(drone_id):  # the link dropped as it went: not the drone's fault
                    await self._heard_again(drone_id, name)
                    continue
                if attempt == DELIVERY_TRIES:
                    raise
                attempt += 1
                self.log("warn", f"{drone_id}: no answer to {name}, sending it again ({attempt}/{DELIVERY_TRIES})")
            except CommandRejected as exc:
                if exc.code == STATE_UNKNOWN:  # the ground stopped hearing it before the mission heard so
                    await self._heard_again(drone_id, name)
                    continue
                if not (wait_clear and exc.code == CONFLICT and exc.other) or self.clock.monotonic() > give_up:
                    raise
                if waited_for != exc.other:
                    waited_for = exc.other
                    self.log("info", f"{drone_id}: {name} waits for {exc.other} to clear the spot ({exc.reason})")
                await self.next_telemetry(exc.other)

    def _out_of_reach(self, drone_id: str) -> bool:
        back = self._link_back_at.get(drone_id)
        return back is not None and not back.done()

    async def _heard_again(self, drone_id: str, name: str) -> None:
        """Wait until the drone is back in reach: until the ground reports it back when
        the mission knows it lost it, else until its next telemetry. Never longer than
        mission.link_grace_s: the mission ends then (link_lost) and this is cancelled."""
        self.log("info", f"{drone_id}: {name} waits for the link to come back")
        if self._out_of_reach(drone_id):
            await asyncio.shield(self._link_back_at[drone_id])
        else:
            await self.next_telemetry(drone_id)

    async def push(self, drone_id: str, body: dict[str, Any]) -> BundleRecord:
        """Send a task bundle as this mission and wait until it has ended (SPEC §6);
        the agent's record is the outcome. Refusals end the mission as `execute`'s do."""
        self.check_assigned(drone_id)
        self._pushed += 1  # fast time replays exactly: its ids come from the mission
        bundle_id = f"b-{self.id}-{self._pushed}" if self.deterministic else new_bundle_id()
        timeout_s = body.get("timeout_s")
        deadline = self.clock.monotonic() + (timeout_s if timeout_s is not None else BUNDLE_NO_TIMEOUT_S)
        pending = _PendingBundle(drone_id, bundle_id, deadline, asyncio.get_running_loop().create_future())
        self._bundles[bundle_id] = pending
        try:
            with self._sending("push", drone_id):
                await self.station.push(drone_id, json.dumps({**body, "bundle_id": bundle_id}).encode(), self.id)
                return await self._outcome(pending.done, drone_id)
        finally:
            self._bundles.pop(bundle_id, None)

    @contextlib.contextmanager
    def _sending(self, name: str, drone_id: str) -> Iterator[None]:
        """What a failed send means for the mission: the ground's 400 → cmd_parse, a
        refusal or no answer from the drone → cmd_exec."""
        try:
            yield
        except InvalidMessage as exc:
            raise self.setback("cmd_parse", f"{name} {drone_id}: {exc}") from None
        except CommandRejected as exc:
            cause = "geofence" if exc.code == FENCE else "cmd_exec"
            raise self.setback(cause, f"{name} {drone_id} refused: {exc.reason}") from None
        except Unreachable as exc:
            raise self.setback("cmd_exec", f"{name} {drone_id}: no answer from the drone ({exc})") from None

    async def _outcome(self, fut: asyncio.Future[T], drone_id: str) -> T:
        """Wait for a command's or bundle's end. A stopped subroutine stops what it
        sent too, before whoever waits on the subroutine sends the next thing."""
        try:
            return await fut
        except asyncio.CancelledError:
            if not self.ending:
                await asyncio.shield(self._cancel_quietly(drone_id))
            raise

    async def _cancel_quietly(self, drone_id: str) -> None:
        try:
            await self.station.command(drone_id, b'{"cmd": "cancel"}', self.id)
        except Exception as exc:  # noqa: BLE001 - best effort; the mission goes on
            self.log("warn", f"{drone_id}: could not cancel the stopped subroutine's command: {exc}")


def mark_ended(record: MissionRecord, cause: str, message: str | None) -> tuple[Literal["info", "warn", "error"], str]:
    """Set the record's status, cause and message for `cause`; returns the log line that says so."""
    status, default = CAUSES[cause]
    record.status, record.cause, record.message = status, cause, message or default
    level: Literal["info", "warn", "error"] = "info" if status == "finished" else ("warn" if status == "cancelled" else "error")
    return level, f"Mission {status}: {cause}" + (f" - {message}" if message else "")


async def leave(station: FleetPort, mission_id: str, drone_id: str, *, critical: bool,
                log: Callable[[Literal["info", "warn", "error"], str], None]) -> None:
    """What a mission's end does to one of its drones: hold it if flying (or send it
    home, by config or at critical battery), then release it."""
    registry = station.registry
    settings = station.config.mission
    if drone_id in registry:
        info = registry.info(drone_id)
        telem = registry.telemetry(drone_id)
        flying = telem.armed and telem.landed_state != "on_ground"
        action = None
        if (critical and settings.return_on_critical_battery) or (flying and settings.end_action == "return"):
            action = "return"
        elif info.state == "active" and info.current_command is not None \
                and not (flying and info.current_command.command in HOMEWARD):
            # Never hold a drone on its way home (outside a fence, say). On the ground a
            # cancel is harmless and clears a return whose end the ground never heard.
            action = "cancel"
        if action is not None:
            try:
                await station.command(drone_id, json.dumps({"cmd": action}).encode(), mission_id)
                log("info", f"{drone_id}: {'return to launch' if action == 'return' else 'hold'} at mission end")
            except Exception as exc:  # noqa: BLE001 - the drone is released anyway
                log("warn", f"{drone_id}: could not {action} at mission end: {exc}")
    station.release(drone_id)


def script_frame(exc: BaseException) -> tuple[str, int | None]:
    """The file (`<mission m3>`, `<plugin x.py>`) and line of the innermost script frame."""
    found: tuple[str, int | None] = ("", None)
    for frame in traceback.extract_tb(exc.__traceback__):
        if frame.filename.startswith(("<mission", "<plugin")):
            found = (frame.filename, frame.lineno)
    return found


def script_line(exc: BaseException) -> int | None:
    return script_frame(exc)[1]


__all__ = ["CAUSES", "Mission", "MissionLogLine", "MissionRecord", "MissionStatus", "Stopped"]
