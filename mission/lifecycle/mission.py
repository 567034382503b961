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
import logging
from collections.abc import Callable
from typing import Any, Literal

from dronefleet.bus.clock import Clock
from dronefleet.mission.lifecycle import assignment as a
from dronefleet.mission.lifecycle.delivery import CommandDelivery, leave
from dronefleet.mission.lifecycle.fleet_port import FleetPort, MissionConfig
from dronefleet.mission.lifecycle.greenlets import Scheduler, Subroutine, current_subroutine
from dronefleet.mission.lifecycle.record import (
    Activity,
    CommandResult,
    MissionLogLine,
    MissionOver,
    MissionRecord,
    SecurityViolation,
    mark_ended,
    script_frame,
)
from dronefleet.schemas.about import DEFAULT_ROLES, may_relay
from dronefleet.schemas.bundles import BundleStatus
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.fleet import CRITICAL_BATTERY, DroneInfo, WatchEvent
from dronefleet.schemas.status import GEOFENCE_OUTSIDE, CommandStatus, SystemStatus
from dronefleet.schemas.telemetry import Telemetry

log = logging.getLogger(__name__)
FIELD_PULSE = "sensor/"  # _pulses key prefix of a field sensor's readings (drone ids never contain '/')

CLAIM_TRIES = 3  # picks of free drones when another mission claims one first
STOP_GRACE_S = 1.0
FREE_STATES = frozenset({"ready", "hold"})


class Mission:
    """The shell: what runs as the mission's main subroutine comes from `script_main`
    (mission.script.ScriptMission runs a mission script there)."""

    def __init__(
        self,
        record: MissionRecord,
        station: FleetPort,
        clock: Clock,
        *,
        deterministic: bool = False,
        on_change: Callable[[Mission], None] = lambda m: None,
        on_log: Callable[[Mission, MissionLogLine], None] = lambda m, line: None,
    ) -> None:
        self.record = record
        self.station = station
        self.config: MissionConfig = station.config
        self.clock = clock
        self.deterministic = deterministic
        self.uid = record.mission_id  # what its deterministic ids derive from (a journalled run: its own)
        self._on_change = on_change
        self._on_log = on_log
        self.scheduler: Scheduler | None = None
        self.requests: dict[str, a.Request] = {}  # drone id → how it was assigned
        self.plugin_drones: dict[str, str] = {}  # drone id → the plugin that assigned it (its relays, its replacements)
        self.commands: list[CommandResult] = []
        self._pulses: dict[str, list[asyncio.Future[None]]] = {}
        self._ended = asyncio.Event()
        self._stop_listening: Callable[[], None] | None = None
        self._critical: set[str] = set()
        self._link_waits: dict[str, asyncio.Task[None]] = {}  # drone id → its link-grace timer
        self.given_up: dict[str, float] = {}  # a plugin's drone → when it was last unreachable past the grace
        # What its subroutines do (/events `subroutine`): set by whoever hosts the mission.
        self.on_activity: Callable[[Mission, Activity], None] = lambda m, activity: None
        # A prediction's host (the preflight, ADR 0014): told of each read whose value a
        # prediction cannot know (a sensor, the field sensors heard, the radio), with the
        # script's line; None when nothing is predicted.
        self.on_unknowable: Callable[[Mission, int | None, str], None] | None = None
        self._doing: dict[str, tuple[Any, ...]] = {}  # subroutine → what it last reported
        self._drones_of: dict[str, tuple[str, ...]] = {}  # subroutine → the drones its last verb on drones acted on
        self._heard_at: dict[str, float] = {}  # drone id → when its telemetry last came (mission clock)
        self.delivery = CommandDelivery(self)  # what it sent and waits for (mission/lifecycle/delivery.py)

    @property
    def id(self) -> str:
        return self.record.mission_id

    @property
    def ending(self) -> bool:
        return self.record.cause is not None

    # ---- log and record -----------------------------------------------------------

    def log(self, level: Literal["info", "warn", "error"], message: str) -> None:
        self._on_log(self, MissionLogLine(timestamp=self.clock.time_ms(), level=level, message=message))

    def report(self, sub: Subroutine | None, event: Literal["verb", "waiting"], verb: str, *, line: int | None = None,
               drones: list[str] | None = None, waiting_on: str | None = None) -> None:
        """A subroutine calls a verb or waits: reported once until it does something else
        (a loop of `wait(drone)` is one report)."""
        if sub is None:
            return
        doing = (event, verb, line, tuple(drones or ()), waiting_on)
        if self._doing.get(sub.sid) == doing:
            return
        self._doing[sub.sid] = doing
        if drones:
            self._drones_of[sub.sid] = tuple(drones)
        self._activity(sub, event, verb=verb, line=line, drones=drones or [], waiting_on=waiting_on)

    def _started_or_ended(self, event: str, sub: Subroutine) -> None:
        if event == "started":
            self._activity(sub, "started")
        else:
            self._doing.pop(sub.sid, None)
            self._activity(sub, "ended", status=sub.outcome)

    def _activity(self, sub: Subroutine, event: Literal["started", "verb", "waiting", "ended"], **fields: Any) -> None:
        self.on_activity(self, Activity(
            mission_id=self.id, timestamp=self.clock.time_ms(), subroutine=sub.sid, name=sub.name, event=event,
            parent=sub.parent.sid if sub.parent is not None else None, plugin=sub.plugin, **fields))

    def changed(self) -> None:
        self.record.active_drones = sorted(self.requests)
        self._on_change(self)

    # ---- life cycle ---------------------------------------------------------------

    async def run(self) -> MissionRecord:
        """Run the script to its end (or the mission's), then clean up. Never raises."""
        self.record.status = "running"
        self.record.start = self.clock.time_ms()
        self.changed()
        self.log("info", "Mission started")
        self._stop_listening = self.station.listen(self._on_event)
        self.scheduler = Scheduler(self._on_error, deterministic=self.deterministic)
        self.scheduler.on_activity = self._started_or_ended
        main = self.script_main()
        try:
            self.scheduler.spawn(main, name="main")
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

    def script_main(self) -> Callable[[], None]:
        """What runs as the main subroutine, once the scheduler exists."""
        raise NotImplementedError

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
        self.delivery.stop()
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
        if not in_plugin and where is not None:
            self.record.line = where
        if isinstance(exc, SecurityViolation):
            self.end("security", f"{prefix}{exc}")
        elif isinstance(exc, MemoryError):  # a mission's process is limited by mission.max_memory_mb
            self.end("security", f"{prefix}the script ran out of memory (mission.max_memory_mb)")
        elif isinstance(exc, Exception) and in_plugin:
            self.end("plugin_error", f"{prefix}{type(exc).__name__}: {exc} (in {sub.name})")
        elif isinstance(exc, Exception):  # UnitError, NameError, ZeroDivisionError, …
            drones = self._drones_of.get(sub.sid, ())
            self.end("script", f"{prefix}{type(exc).__name__}: {exc} (in subroutine {sub.name}"
                               + (f", on {', '.join(drones)})" if drones else ")"))
        else:
            self.end("unexpected", f"{prefix}{type(exc).__name__}: {exc}")

    # ---- events from the station --------------------------------------------------

    def _on_event(self, event: WatchEvent) -> None:
        data = event.data
        if event.kind == "telemetry":
            self._on_telemetry(data)
        elif event.kind == "status":
            if isinstance(data, CommandStatus):
                self.delivery.heard_command_status(data, assigned=data.drone_id in self.requests)
            elif isinstance(data, BundleStatus):
                self.delivery.heard_bundle_status(data)
            elif isinstance(data, SystemStatus) and data.drone_id in self.requests:
                self._on_system_status(data)
        elif event.kind == "drone" and data.drone_id in self.requests:
            self._on_drone(data)
        elif event.kind == "field_sensor":
            self._pulse(f"{FIELD_PULSE}{data.sensor_id}")

    def _on_telemetry(self, telem: Telemetry) -> None:
        self._heard_at[telem.drone_id] = self.clock.monotonic()
        if telem.drone_id in self.requests:
            self.delivery.heard(telem)
        self._pulse(telem.drone_id)

    def heard_within(self, drone_id: str, seconds: float) -> bool:
        """Whether the drone's telemetry came in the last `seconds`."""
        at = self._heard_at.get(drone_id)
        return at is not None and self.clock.monotonic() - at <= seconds

    def _pulse(self, key: str) -> None:
        waiters = self._pulses.pop(key, None)
        for fut in waiters or ():
            if not fut.done():
                fut.set_result(None)

    def _on_system_status(self, status: SystemStatus) -> None:
        reason = status.reason or ""
        if status.state == "failsafe" and GEOFENCE_OUTSIDE in reason:
            self.end("geofence", f"{status.drone_id} was found {reason.removeprefix('return: ')}; it returns")
        elif status.state == "return":
            self.end("return", f"{status.drone_id} started an automatic return to launch" + (f": {status.reason}" if status.reason else ""))
        elif status.state == "start_manual":
            self.end("manual", f"{status.drone_id} is under manual control")

    def _on_drone(self, info: DroneInfo) -> None:
        if info.state in ("unknown", "unreachable"):  # unheard, or heard with no route to its commands
            self._link_lost(info.drone_id, "" if info.state == "unknown"
                            else " (heard, but its commands cannot reach it: no route to its agent's queryable)")
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
            if request is not None:
                missing = sorted(a.sensors_of(request) - set(info.sensors))
                if missing:
                    self.end("sensor", f"{info.drone_id} lost its {', '.join(missing)} sensor")

    def _link_lost(self, drone_id: str, why: str = "") -> None:
        """A drone out of reach is not yet a failure: it may be flying back into range
        (or finishing work alone). Wait `mission.link_grace_s` for it."""
        if drone_id in self._link_waits or self.ending:
            return
        grace = self.config.mission.link_grace_s
        alone = self.delivery.bundles_of(drone_id)
        if alone:  # working alone is not a failure: the grace counts from the bundle's end
            ends_in = max(0.0, max(b.deadline for b in alone) - self.clock.monotonic())
            self.log("info", f"{drone_id}: link lost while it runs bundle {alone[0].bundle_id}{why}; waiting up to "
                             f"{ends_in + grace:.0f} s (its timeout, then mission.link_grace_s)")
            grace += ends_in
        else:
            self.log("warn", f"{drone_id}: link lost{why}; waiting up to {grace:g} s for it to come back")
        self.delivery.out_of_reach_from_now(drone_id)
        self._link_waits[drone_id] = asyncio.get_running_loop().create_task(
            self._link_grace(drone_id, grace), name=f"mission {self.id} link grace {drone_id}",
        )

    async def _link_grace(self, drone_id: str, grace_s: float) -> None:
        await self.clock.sleep(grace_s)
        self._link_waits.pop(drone_id, None)
        message = f"{drone_id} unreachable for {grace_s:g} s (mission.link_grace_s)"
        plugin = self.plugin_drones.get(drone_id)
        if plugin is not None:  # a relay, a replacement: the plugin's problem (SPEC §5), it plans without the drone
            self.given_up[drone_id] = self.clock.monotonic()
            self.log("warn", f"plugin {plugin}: {message}; the plugin goes on")
            return
        self.end("link_lost", message)

    def _link_back(self, drone_id: str) -> None:
        wait = self._link_waits.pop(drone_id, None)
        if wait is not None:
            wait.cancel()
            self.log("info", f"{drone_id}: link restored, the mission goes on")
        self.delivery.back_in_reach(drone_id, caught_up=wait is not None)

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
                relay=may_relay(relays, drone_id, info.roles),
                kind=info.kind,
                roles=frozenset(info.roles) if info.roles is not None else frozenset(DEFAULT_ROLES),
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
        sub = current_subroutine()
        if sub is not None and sub.plugin is not None:
            self.plugin_drones[drone_id] = sub.plugin
        if drone_id not in self.record.used_drones:
            self.record.used_drones.append(drone_id)
        self.log("info", f"Assigned {drone_id} ({a.describe(request)})")
        self.changed()

    def revoke(self, drone_id: str) -> None:
        self.check_assigned(drone_id)
        del self.requests[drone_id]
        self.plugin_drones.pop(drone_id, None)
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

    async def next_field_reading(self, sensor_id: str) -> None:
        """Until field sensor `sensor_id` publishes again (any of its types)."""
        await self.next_telemetry(f"{FIELD_PULSE}{sensor_id}")

    async def next_telemetry(self, drone_id: str) -> None:
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._pulses.setdefault(drone_id, []).append(fut)
        await fut
