"""Command delivery, the part of a mission's life cycle that talks to its drones:
send a command or a task bundle as the mission, send it again when no answer comes
(or once the drone is back in reach), learn how it ended, and what each failure
means for the mission (SPEC §5). And what a mission's end does to each drone."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections import deque
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from typing import Any, Literal, Protocol, TypeVar

from dronefleet.bus.clock import Clock
from dronefleet.bus.port import Unreachable
from dronefleet.mission.lifecycle.fleet_port import FleetPort, MissionConfig
from dronefleet.mission.lifecycle.record import CommandResult, MissionOver
from dronefleet.mission.lifecycle.send_again import TakenBack, deliver, steps_for
from dronefleet.schemas.bundles import BUNDLE_ENDS, BundleRecord, BundleStatus, new_bundle_id
from dronefleet.schemas.errors import CommandRejected, InvalidMessage
from dronefleet.schemas.fence import REASON as FENCE
from dronefleet.schemas.geo import angle_diff_deg, distance_m, normalize_deg
from dronefleet.schemas.status import FAILSAFE_ID_PREFIX, TERMINAL_STATES, CommandStatus, ended_by_failsafe
from dronefleet.schemas.telemetry import Telemetry

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")


# Where a held goto may go now: (lat, lon, why no drone is free for the relays it needs
# or None, what holds it: "at the edge of its relay chain" or "out of drone02's way").
Leash = tuple[float, float, str | None, str]


BUNDLE_NO_TIMEOUT_S = 3600.0  # a bundle without timeout_s: how long the mission expects it may run alone


@dataclass
class PendingBundle:
    drone_id: str
    bundle_id: str
    deadline: float  # clock.monotonic() by which the bundle should have ended
    done: asyncio.Future[BundleRecord]


# A bundle's record is asked again this often, a second apart, before the mission makes
# do with the status it heard: right after a drone came back in range its statuses
# arrived while queries still found no route for 6 s.
RECORD_TRIES, RECORD_RETRY_S = 10, 1.0
OVERDUE_S = 5.0  # a bundle not heard ending this long after its timeout is read from the agent …
OVERDUE_RETRY_S = 30.0  # … and again this often
# Commands with an absolute goal, sent again when the drone's lost-link failsafe ended
# them (relative ones — move by offsets, turn, offboard — would not mean the same again).
RESUMABLE = frozenset({"takeoff", "goto", "return", "land"})
RESUME_TRIES = 3
HOMEWARD = frozenset({"return", "land"})  # left running when a mission ends
ARRIVED_M, ARRIVED_S = 1.0, 10.0  # a goto whose drone stands this close to its target this long has ended
FACING_DEG = 5.0  # a turn whose drone faces this close to its new heading that long has ended (the agent ends it at 2)
LEASH_LIMIT_S = 120.0  # a goto held this long with no drone free for the relays it needs ends the mission
FLOWN = frozenset({"goto", "turn"})  # commands a drone on the ground cannot do
ALOFT_KEPT = 600  # heights in the air kept per drone (a minute at 10 Hz): where a failsafe found it
HOLD_LIMIT_S = 600.0  # a goto held this long without its edge moving ends the mission, whatever holds it
LEASH_STEP_M = 2.0  # a held goto is sent on when the edge moves this far


class MissionSide(Protocol):
    """What delivery needs of the mission it sends for (mission/lifecycle/mission.py)."""

    station: FleetPort
    config: MissionConfig
    clock: Clock
    deterministic: bool
    uid: str  # what its deterministic bundle ids derive from
    commands: list[CommandResult]
    plugin_drones: dict[str, str]
    given_up: dict[str, float]

    @property
    def id(self) -> str: ...
    @property
    def ending(self) -> bool: ...
    def log(self, level: Literal["info", "warn", "error"], message: str) -> None: ...
    def fail(self, cause: str, message: str) -> MissionOver: ...
    def setback(self, cause: str, message: str) -> MissionOver: ...
    def check_assigned(self, drone_id: str) -> None: ...
    async def next_telemetry(self, drone_id: str) -> None: ...


class CommandDelivery:
    """A mission's sending half: what it sent and waits for, and how each send goes
    (the mission holds one, `Mission.delivery`, and hears the statuses that end them)."""

    def __init__(self, mission: MissionSide) -> None:
        self.mission = mission
        self.sent: dict[str, SentCommand] = {}  # command id → the command a verb waits on, and its outcome
        self.bundles: dict[str, PendingBundle] = {}  # bundle id → the push waiting for it
        self._pushed = 0
        self.link_back_at: dict[str, asyncio.Future[None]] = {}  # resolved when a lost drone is back
        self._asks: set[asyncio.Task[None]] = set()  # bundle records being read (catch_up)
        # A plugin that keeps drones connected may leash their gotos (relay mode "chain"):
        # (drone, lat, lon, alt) → None (go) or (lat, lon, why it cannot go on or None, what holds it).
        self.leash: Callable[[str, float, float, float | None], Leash | None] | None = None
        self.leashed: dict[str, tuple[float, float, float | None]] = {}  # drone → the goal of its held goto
        # Its lost-link failsafe flying a drone home or down: when it began (the agent's ms),
        # until the mission sends it home itself, stops that return or takes it up again.
        self.failsafe_homeward: dict[str, int] = {}
        self.aloft: dict[str, deque[tuple[int, float]]] = {}  # drone → (ms, m above home) while in the air
        self.standing: dict[str, bool] = {}  # drone → on the ground, at its last sample
        self.failsafe_down: set[str] = set()  # drones the failsafe's return or landing brought down

    # What the send-again steps (send_again.Sender) ask of the mission, through it.
    @property
    def clock(self) -> Clock:
        return self.mission.clock

    def log(self, level: Literal["info", "warn", "error"], message: str) -> None:
        self.mission.log(level, message)

    def setback(self, cause: str, message: str) -> MissionOver:
        return self.mission.setback(cause, message)

    async def next_telemetry(self, drone_id: str) -> None:
        await self.mission.next_telemetry(drone_id)

    async def execute(self, drone_id: str, body: dict[str, Any], *, wait: bool = True,
                      wait_clear: bool = False) -> CommandStatus | None:
        """Send one command as this mission; with `wait`, return its terminal status.

        Failures end the mission: the ground's 400 → cmd_parse, a refusal, a failure
        status or no answer → cmd_exec, anything else → unexpected.
        """
        name = str(body["cmd"])
        if name in HOMEWARD or name == "disarm":  # sent home by the mission itself now
            self._failsafe_over(drone_id)
        if name == "goto" and self.leash is not None and drone_id not in self.mission.plugin_drones and "lat" in body:
            await self._on_leash(drone_id, body)
        sent_at = self.clock.monotonic()
        for interrupted in range(RESUME_TRIES + 1):
            try:
                status = await self._execute_once(drone_id, name, body, wait=wait, wait_clear=wait_clear,
                                                  take_back=interrupted > 0 or not self._sent_home(drone_id))
            except TakenBack:
                status = await self._execute_once(drone_id, name, body, wait=wait, wait_clear=wait_clear)
            if status is None or not ended_by_failsafe(status) or name not in RESUMABLE:
                break
            if self.mission.given_up.get(drone_id, -1.0) >= sent_at:  # the plugin went on without it: not sent out again
                raise self.setback("cmd_exec", f"{name} {drone_id} ended by its lost-link failsafe after "
                                               f"{self.mission.config.mission.link_grace_s:g} s out of reach; not sent again")
            if interrupted == RESUME_TRIES:
                self.log("warn", f"{drone_id}: {name} interrupted by its lost-link failsafe {RESUME_TRIES + 1} times; "
                                 "going on without it")
                break
            # The drone held (or turned home) on its own while out of reach; the script
            # still wants this done, so it is sent again once the drone can hear it.
            self.log("warn", f"{drone_id}: {name} was interrupted by the drone's lost-link failsafe; sending it again")
        return status

    def _sent_home(self, drone_id: str) -> bool:
        """The mission's own last command to the drone was a return or a landing: a goto
        refused then is the script's doing, not the failsafe's, and is not taken back."""
        last = next((c for c in reversed(self.mission.commands) if c.drone_id == drone_id), None)
        return last is not None and last.cmd in HOMEWARD

    async def _on_leash(self, drone_id: str, body: dict[str, Any]) -> None:
        """A goto beyond what the relays cover goes as far as they do, and on as they
        arrive (`leash`); held with no drone free for the relays it needs, for
        LEASH_LIMIT_S, the mission ends `requirements` naming them. Liveness (ADR 0006):
        held for any reason with its edge never moving LEASH_STEP_M for HOLD_LIMIT_S,
        the mission ends `requirements` saying what held it, never a silent hold."""
        goal = (float(body["lat"]), float(body["lon"]), float(body["alt"]) if "alt" in body else None)
        sent: tuple[float, float] | None = None
        said: str | None = None
        stuck_since: float | None = None
        edge: tuple[float, float, float] | None = None  # where the edge stood, and since when
        try:
            while self.leash is not None and (verdict := self.leash(drone_id, *goal)) is not None:
                lat, lon, stuck, why = verdict
                self.leashed[drone_id] = goal
                now = self.clock.monotonic()
                if said != why:
                    said = why
                    short = distance_m(lat, lon, goal[0], goal[1])
                    self.log("info", f"{drone_id}: held {why}, {short:.0f} m short of its goal")
                stuck_since = (stuck_since or now) if stuck else None
                if stuck and stuck_since is not None and now - stuck_since >= LEASH_LIMIT_S:
                    raise self.mission.fail("requirements", f"{stuck} (held {LEASH_LIMIT_S:g} s)")
                if edge is None or distance_m(lat, lon, edge[0], edge[1]) > LEASH_STEP_M:
                    edge = (lat, lon, now)
                elif now - edge[2] >= HOLD_LIMIT_S:
                    raise self.mission.fail("requirements", f"{drone_id} held {why} for {HOLD_LIMIT_S:g} s, "
                                                            f"{distance_m(lat, lon, goal[0], goal[1]):.0f} m short of its goal"
                                                            + (f": {stuck}" if stuck else ""))
                if (sent is None or distance_m(lat, lon, *sent) > LEASH_STEP_M or self._idle_at(drone_id, sent, (lat, lon))) and \
                        await self._leash_step(drone_id, {**body, "lat": lat, "lon": lon, **self._leg_level(drone_id, goal[2])}):
                    sent = (lat, lon)
                await self.next_telemetry(drone_id)
        finally:
            self.leashed.pop(drone_id, None)
        if said:
            self.log("info", f"{drone_id}: nothing holds it any more; going on to its goal")

    def _idle_at(self, drone_id: str, sent: tuple[float, float], edge: tuple[float, float]) -> bool:
        """The drone stands where its last leg took it and the edge moved, if less than
        LEASH_STEP_M: a short leg is sent too (a drone just outside what covers it, told
        back 1.3 m, was never sent and held to the time limit)."""
        t = self.mission.station.registry.telemetry(drone_id) if drone_id in self.mission.station.registry else None
        if t is None or t.position is None or distance_m(*edge, *sent) < 0.5:
            return False
        return distance_m(t.position.lat, t.position.lon, *sent) < LEASH_STEP_M

    def _leg_level(self, drone_id: str, alt: float | None) -> dict[str, float]:
        """A leg short of the goal keeps the drone's level when the goal is lower: the
        descent is the last leg's. (A goto home at field level, held 65 m short, flew its
        leg down to the ground and could go no further.)"""
        t = self.mission.station.registry.telemetry(drone_id) if drone_id in self.mission.station.registry else None
        if alt is None or t is None or t.position is None or t.position.alt <= alt:
            return {}
        return {"alt": t.position.alt}

    async def _leash_step(self, drone_id: str, body: dict[str, Any]) -> bool:
        """One leg of a held goto, not waited for. Refused (another drone's spot, say) or
        unanswered, the drone stays where it is and the leg is tried again as it reports."""
        payload = json.dumps({**body, "command_id": self.mission.station.new_command_id()}).encode()
        try:
            await self.mission.station.command(drone_id, payload, self.mission.id)
        except (CommandRejected, InvalidMessage, Unreachable) as exc:
            log.info("mission %s: %s: a leg toward the chain's edge was not taken (%s)", self.mission.id, drone_id, exc)
            return False
        self._bundles_ended_by(drone_id, "goto")
        return True

    async def _execute_once(self, drone_id: str, name: str, body: dict[str, Any], *, wait: bool,
                            wait_clear: bool, take_back: bool = False) -> CommandStatus | None:
        self.mission.check_assigned(drone_id)
        if self.out_of_reach(drone_id):  # the ground would refuse it (unknown)
            await self.heard_again(drone_id, name)
        if (take_back and name in FLOWN and self.brought_home(drone_id)
                and (drone_id in self.failsafe_down or self.standing.get(drone_id))):
            # Landed, armed or not yet disarmed: the autopilot would refuse to fly it there.
            await self.relaunch(drone_id, name)
        command_id = self.mission.station.new_command_id()
        fut: asyncio.Future[CommandStatus] = asyncio.get_running_loop().create_future()
        if wait:
            self.sent[command_id] = SentCommand(drone_id, name, self.clock.monotonic(), fut)
        sent = self.clock.time_ms()
        arrived = self._arrival(drone_id, name, body)  # read before it goes: a turn's heading is the one it turns from
        try:
            with self._sending(name, drone_id):
                payload = json.dumps({**body, "command_id": command_id}).encode()
                await self._deliver(drone_id, name, lambda: self.mission.station.command(drone_id, payload, self.mission.id), wait_clear,
                                    take_back)
                self._bundles_ended_by(drone_id, name)
                if not wait:
                    return None
                self.sent[command_id].accepted = self.clock.monotonic()
                if arrived is not None:
                    status = await self._outcome_or_there(fut, drone_id, command_id, name, arrived)
                else:
                    status = await self._outcome(fut, drone_id)
        except (asyncio.CancelledError, MissionOver, TakenBack):
            raise
        except Exception as exc:  # noqa: BLE001
            log.exception("mission %s: %s %s", self.mission.id, name, drone_id)
            raise self.mission.fail("unexpected", f"{name} {drone_id}: {type(exc).__name__}: {exc}") from None
        finally:
            self.sent.pop(command_id, None)
        target: dict[str, float] | None = {k: float(body[k]) for k in ("lat", "lon", "alt") if k in body} or None
        self.mission.commands.append(CommandResult(
            drone_id=drone_id, cmd=name, t_sent_ms=sent, t_end_ms=self.clock.time_ms(), state=status.state, target=target,
        ))
        if status.state == "failure":
            raise self.setback("cmd_exec", f"{name} {drone_id} failed: {status.reason or 'no reason given'}")
        return status

    async def _deliver(self, drone_id: str, name: str, send: Callable[[], Awaitable[R]], wait_clear: bool = False,
                       take_back: bool = False) -> R:
        """Send a command or bundle (`send`: the ground's reply) until it goes through or
        a failure ends the mission; each reason to send again is a step of
        mission/lifecycle/send_again.py. With `wait_clear`, a target another drone holds
        is waited for; with `take_back` (the mission did not send the drone home itself),
        a drone its lost-link failsafe is flying home is stopped first, once: it hears the
        ground again, and the mission still wants it where it was going."""
        return await deliver(send, steps_for(self, drone_id, name, wait_clear=wait_clear, take_back=take_back))

    @property
    def link_grace_s(self) -> float:
        return self.mission.config.mission.link_grace_s

    @property
    def clear_wait_s(self) -> float:
        return self.mission.config.mission.clear_wait_s

    async def cancel(self, drone_id: str) -> None:
        """Stop what the drone is doing (its failsafe's return), as this mission."""
        self._failsafe_over(drone_id)
        body = {"cmd": "cancel", "command_id": self.mission.station.new_command_id()}
        await self.mission.station.command(drone_id, json.dumps(body).encode(), self.mission.id)

    def heard(self, telem: Telemetry) -> None:
        """Each sample of an assigned drone: whether it stands, its height while in the air."""
        self.standing[telem.drone_id] = telem.landed_state == "on_ground"
        if telem.landed_state == "in_air" and telem.position is not None:
            kept = self.aloft.setdefault(telem.drone_id, deque(maxlen=ALOFT_KEPT))
            kept.append((telem.timestamp, telem.position.rel_alt))

    def heard_status(self, status: CommandStatus) -> None:
        """The drone's failsafe flew it home or down (the statuses of what an agent sends
        itself come, at the latest, once it hears the ground again)."""
        if (status.command_id.startswith(FAILSAFE_ID_PREFIX) and status.command in HOMEWARD
                and status.state in ("start", "finish", "success")):  # not its end when stopped
            # A start sent into the dark may be lost, its end sent again later: the first heard.
            self.failsafe_homeward.setdefault(status.drone_id, status.timestamp)
            if status.state in ("finish", "success"):  # a return or landing ends on the ground
                self.failsafe_down.add(status.drone_id)

    def heard_command_status(self, status: CommandStatus, *, assigned: bool) -> None:
        """A command's status from any drone (`assigned`: one of this mission's): the
        end of a command a verb waits on, and what its start ends."""
        if assigned:
            self.heard_status(status)
        sent = self.sent.get(status.command_id)
        if sent is not None and status.state in TERMINAL_STATES and not sent.outcome.done():
            sent.outcome.set_result(status)
        if status.state == "start":
            self.superseded_unheard(status)

    def heard_bundle_status(self, status: BundleStatus) -> None:
        pending = self.bundles.get(status.bundle_id)
        if pending is not None and status.ends_bundle:
            self.catch_up(pending, status)

    def bundles_of(self, drone_id: str) -> list[PendingBundle]:
        """The bundles this mission waits on that run on the drone."""
        return [b for b in self.bundles.values() if b.drone_id == drone_id]

    def out_of_reach_from_now(self, drone_id: str) -> None:
        """The ground lost the drone: what is sent to it waits until it is back."""
        self.link_back_at.setdefault(drone_id, asyncio.get_running_loop().create_future())

    def back_in_reach(self, drone_id: str, *, caught_up: bool) -> None:
        """The ground has the drone again; with `caught_up`, the end of each bundle it ran
        while out of reach is read from its agent (statuses sent then never arrived)."""
        back = self.link_back_at.pop(drone_id, None)
        if back is not None and not back.done():
            back.set_result(None)
        if caught_up:
            for pending in self.bundles_of(drone_id):
                self.catch_up(pending)

    def catch_up(self, pending: PendingBundle, status: BundleStatus | None = None, *,
                 superseded: str | None = None) -> None:
        """Ask the agent for the bundle's record (its whole history); resolve the push
        if the bundle has ended. Statuses sent while the link was down never arrived.
        An end known without its record (`status` heard, or `superseded`: the drone
        accepted what ends it, and why) resolves the push once the record stays unread."""
        async def ask() -> None:
            for attempt in range(1, RECORD_TRIES + 1):
                try:
                    record = await self.mission.station.bundle_record(pending.drone_id, pending.bundle_id)
                    break
                except (CommandRejected, Unreachable) as exc:
                    if pending.done.done():
                        return
                    if attempt < RECORD_TRIES:  # a route just back may carry statuses before queries
                        await self.clock.sleep(RECORD_RETRY_S)
                        continue
                    if superseded is not None:
                        self.log("warn", f"{pending.drone_id}: could not read bundle {pending.bundle_id} ({exc}); "
                                         f"it was cancelled: {superseded}")
                        record = BundleRecord(bundle_id=pending.bundle_id, state="cancelled", reason=superseded)
                        break
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

        task = asyncio.get_running_loop().create_task(ask(), name=f"mission {self.mission.id} bundle {pending.bundle_id}")
        self._asks.add(task)
        task.add_done_callback(self._asks.discard)

    def stop(self) -> None:
        """The mission ends: nothing it sent is waited on any more."""
        for sent in self.sent.values():
            if not sent.outcome.done():
                sent.outcome.cancel()
        for pending in self.bundles.values():
            if not pending.done.done():
                pending.done.cancel()
        for ask in list(self._asks):
            ask.cancel()

    def brought_home(self, drone_id: str) -> bool:
        return drone_id in self.failsafe_homeward

    def _failsafe_over(self, drone_id: str) -> None:
        self.failsafe_homeward.pop(drone_id, None)
        self.failsafe_down.discard(drone_id)

    async def relaunch(self, drone_id: str, name: str) -> None:
        self.log("warn", f"{drone_id}: its lost-link failsafe brought it home or down; arming it and taking it back "
                         f"up to send {name} again")
        began = self.failsafe_homeward[drone_id]
        self._failsafe_over(drone_id)
        before = [alt for at, alt in self.aloft.get(drone_id, ()) if at <= began]
        await self.execute(drone_id, {"cmd": "arm"})
        await self.execute(drone_id, {"cmd": "takeoff", **({"alt": round(before[-1], 1)} if before else {})})

    def out_of_reach(self, drone_id: str) -> bool:
        back = self.link_back_at.get(drone_id)
        return back is not None and not back.done()

    async def heard_again(self, drone_id: str, name: str) -> None:
        """Wait until the drone is back in reach: until the ground reports it back when
        the mission knows it lost it, else until its next telemetry. Never longer than
        mission.link_grace_s: the mission ends then (link_lost) and this is cancelled."""
        self.log("info", f"{drone_id}: {name} waits for the link to come back")
        if self.out_of_reach(drone_id):
            await asyncio.shield(self.link_back_at[drone_id])
        else:
            await self.next_telemetry(drone_id)

    async def next_heard_within(self, drone_id: str, seconds: float) -> bool:
        """Whether the drone's next telemetry comes within `seconds`."""
        heard = asyncio.ensure_future(self.next_telemetry(drone_id))
        nap = asyncio.ensure_future(self.clock.sleep(seconds))
        try:
            await asyncio.wait({heard, nap}, return_when=asyncio.FIRST_COMPLETED)
            return heard.done() and not heard.cancelled()
        finally:
            heard.cancel()
            nap.cancel()

    async def push(self, drone_id: str, body: dict[str, Any]) -> BundleRecord:
        """Send a task bundle as this mission and wait until it has ended (SPEC §6);
        the agent's record is the outcome. Refusals end the mission as `execute`'s do;
        unanswered, it is sent again as a command is (the same bundle id: the agent runs
        it once). Sent once only, a relay's homeward bundle lost on a lossy hop unwound
        the plugin's routine and left the relay hovering on its spot, where another passed
        1.1 m from it."""
        self.mission.check_assigned(drone_id)
        self._pushed += 1  # fast time replays exactly: its ids come from the mission
        bundle_id = f"b-{self.mission.uid}-{self._pushed}" if self.mission.deterministic else new_bundle_id()
        timeout_s = body.get("timeout_s")
        deadline = self.clock.monotonic() + (timeout_s if timeout_s is not None else BUNDLE_NO_TIMEOUT_S)
        pending = PendingBundle(drone_id, bundle_id, deadline, asyncio.get_running_loop().create_future())
        self.bundles[bundle_id] = pending
        try:
            with self._sending("push", drone_id):
                payload = json.dumps({**body, "bundle_id": bundle_id}).encode()
                reply = await self._deliver(drone_id, "push", lambda: self.mission.station.push(drone_id, payload, self.mission.id))
                self._bundles_ended_by(drone_id, "push", bundle_id)
                if reply.reason:  # a push sent again that the agent had taken: its end may have gone by
                    self.catch_up(pending)
                overdue = asyncio.ensure_future(self._overdue(pending))
                try:
                    return await self._outcome(pending.done, drone_id)
                finally:
                    overdue.cancel()
        finally:
            self.bundles.pop(bundle_id, None)

    async def _overdue(self, pending: PendingBundle) -> None:
        """Past its timeout (the agent ends it then) a bundle whose end was not heard is
        read from the agent's record, again every OVERDUE_RETRY_S: a relay's homeward
        bundle whose end went down with a lossy link kept its routine waiting to the
        time limit, nothing else sent to it."""
        await self.clock.sleep(max(0.0, pending.deadline - self.clock.monotonic()) + OVERDUE_S)
        while not pending.done.done():
            self.catch_up(pending)
            await self.clock.sleep(OVERDUE_RETRY_S)

    def _bundles_ended_by(self, drone_id: str, name: str, newer: str | None = None) -> None:
        """A command (`name`) or bundle (`newer`) the drone accepted ends the bundle it was
        running (SPEC §6). Its own end may have gone down with a link that dropped (a
        relay's duty bundle: its routine waited for that end until the time limit): the
        agent's record of every bundle of this mission still running there is read
        again, and if it cannot be read, the bundle is known cancelled all the same (a
        relay sent home across a flapping link: its duty bundle held the mission open
        for its 420 s time limit)."""
        why = f"superseded by bundle {newer}" if newer is not None else f"{name} from the ground"
        for pending in list(self.bundles.values()):
            if pending.drone_id == drone_id and pending.bundle_id != newer and not pending.done.done():
                self.catch_up(pending, superseded=why)

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

    def superseded_unheard(self, start: CommandStatus) -> None:
        """`start` of a command this mission sent: every command it sent the drone before
        (accepted before this one went) has ended — the agent ends a running command when
        another starts (agent/priority.py). If its own end was never heard (lost with a
        link that closed, and not repeated), it is resolved here, or its verb would wait
        for ever."""
        later = self.sent.get(start.command_id)
        if later is None or start.command in KEEP_RUNNING:
            return
        for command_id, earlier in self.sent.items():
            if (earlier.drone_id != start.drone_id or command_id == start.command_id or earlier.name in KEEP_RUNNING
                    or earlier.accepted is None or earlier.accepted > later.sent or earlier.outcome.done()):
                continue
            reason = f"superseded by {start.command} {start.command_id} (its own end was not heard)"
            self.log("info", f"{start.drone_id}: {earlier.name} {reason}")
            earlier.outcome.set_result(CommandStatus(drone_id=start.drone_id, timestamp=start.timestamp, command_id=command_id,
                                         command=earlier.name, state="cancel", reason=reason))

    def _arrival(self, drone_id: str, name: str, body: dict[str, Any]) -> Callable[[Telemetry], bool] | None:
        """For a command whose end shows in the telemetry, what its end looks like: a
        goto's drone still at its target, a turn's still facing its new heading (the one
        the drone faced when the turn was sent, turned by `deg`)."""
        if name == "goto" and "lat" in body:
            lat, lon, alt = float(body["lat"]), float(body["lon"]), float(body["alt"]) if "alt" in body else None
            return lambda t: (t.position is not None and distance_m(t.position.lat, t.position.lon, lat, lon) <= ARRIVED_M
                              and (alt is None or abs(t.position.alt - alt) <= ARRIVED_M) and t.speed <= 0.3)
        if name == "turn" and drone_id in self.mission.station.registry:
            heading = normalize_deg(self.mission.station.registry.telemetry(drone_id).heading + float(body["deg"]))
            return lambda t: abs(angle_diff_deg(t.heading, heading)) <= FACING_DEG and t.speed <= 0.3
        return None

    async def _outcome_or_there(self, fut: asyncio.Future[CommandStatus], drone_id: str, command_id: str, name: str,
                                arrived: Callable[[Telemetry], bool]) -> CommandStatus:
        """A goto's or turn's end, or — its `finish` lost on the way (a reliable
        publication goes down with a link that closes under it) — the drone heard as
        its end leaves it (`arrived`) for ARRIVED_S: the end the agent would have
        reported. (A turn whose finish was lost kept a survey waiting to the time limit.)"""
        watch: asyncio.Future[Any] = asyncio.ensure_future(self._there(drone_id, arrived))
        either: list[asyncio.Future[Any]] = [fut, watch]
        try:
            await asyncio.wait(either, return_when=asyncio.FIRST_COMPLETED)
        except asyncio.CancelledError:  # as _outcome: a stopped subroutine stops its goto
            watch.cancel()
            if not self.mission.ending:
                await asyncio.shield(self._cancel_quietly(drone_id))
            raise
        watch.cancel()
        if fut.done():
            return fut.result()
        where = "stands at its target" if name == "goto" else "faces its new heading"
        self.log("warn", f"{drone_id}: the end of its {name} was not heard; it {where}, going on")
        return CommandStatus(drone_id=drone_id, timestamp=self.clock.time_ms(), command_id=command_id,
                             command=name, state="finish")

    async def _there(self, drone_id: str, arrived: Callable[[Telemetry], bool]) -> None:
        since: float | None = None
        while True:
            await self.next_telemetry(drone_id)
            close = arrived(self.mission.station.registry.telemetry(drone_id))
            now = self.clock.monotonic()
            since = (since or now) if close else None
            if since is not None and now - since >= ARRIVED_S:
                return

    async def _outcome(self, fut: asyncio.Future[T], drone_id: str) -> T:
        """Wait for a command's or bundle's end. A stopped subroutine stops what it
        sent too, before whoever waits on the subroutine sends the next thing."""
        try:
            return await fut
        except asyncio.CancelledError:
            if not self.mission.ending:
                await asyncio.shield(self._cancel_quietly(drone_id))
            raise

    async def _cancel_quietly(self, drone_id: str) -> None:
        try:
            await self.mission.station.command(drone_id, b'{"cmd": "cancel"}', self.mission.id)
        except Exception as exc:  # noqa: BLE001 - best effort; the mission goes on
            self.log("warn", f"{drone_id}: could not cancel the stopped subroutine's command: {exc}")


@dataclass
class SentCommand:
    """A command a verb waits on: to whom, when it was sent and accepted (monotonic),
    and the future its terminal status resolves."""

    drone_id: str
    name: str
    sent: float
    outcome: asyncio.Future[CommandStatus]
    accepted: float | None = None


KEEP_RUNNING = frozenset({"arm", "disarm"})  # commands that end nothing, and that nothing ends


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
        pos = telem.position
        where = f"at {pos.lat:.6f}, {pos.lon:.6f}, {pos.rel_alt:.1f} m above home" if pos is not None else "(no position)"
        if action is not None:
            try:
                await station.command(drone_id, json.dumps({"cmd": action}).encode(), mission_id)
                log("info", f"{drone_id}: {'return to launch' if action == 'return' else 'hold'} at mission end, {where}")
            except Exception as exc:  # noqa: BLE001 - the drone is released anyway
                log("warn", f"{drone_id}: could not {action} at mission end ({exc}): left {where}")
        elif flying:
            homeward = telem.flight_mode in ("return_to_launch", "land") or (
                info.current_command is not None and info.current_command.command in HOMEWARD)
            log("info", f"{drone_id}: left {'on its way down or home' if homeward else 'hovering'} at mission end, {where}")
    station.release(drone_id)
