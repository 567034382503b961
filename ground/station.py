"""The ground station's core shell: the mesh in, the registry in the middle, the log
and the watchers out, and the one path by which commands reach a drone.

Telemetry, statuses, sensor readings and liveliness arrive from the Bus on the event
loop and feed the pure Registry; what it reports goes to the event log (SQLite) and
to every watcher (the HTTP event stream, later missions). Commands from HTTP and
missions pass `command()`: validated, checked against the registry (409 reasons),
stamped, sent as a query to the agent, and answered with the agent's reply.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import msgspec

from dronefleet.bus.clock import Clock, SystemClock
from dronefleet.bus.mesh_security import relays_of
from dronefleet.bus.port import Bus, Declaration, NoRoute, QueryRefused, Sample, Unreachable
from dronefleet.bus.recording import now_ns_of
from dronefleet.bus.redeclarable import Redeclarable
from dronefleet.bus.stream_copy import Stream, StreamCopy
from dronefleet.ground.active_ground import Change
from dronefleet.ground.airspace import Airspace
from dronefleet.ground.config import GroundConfig
from dronefleet.ground.describe import describe_step
from dronefleet.ground.eventlog import EventLog
from dronefleet.ground.feeds import SensorFeeds
from dronefleet.ground.ground_peers import GroundPeers
from dronefleet.ground.inbound import Inbound
from dronefleet.ground.mission_recording import MissionRecordings
from dronefleet.ground.registry import Event, InfoChanged, LogLine, Registry
from dronefleet.schemas.auth import T, signer_of
from dronefleet.schemas.bundles import (
    BundleRecord,
    BundleReply,
    BundleStatus,
    TaskBundle,
    new_bundle_id,
    parse_bundle,
    sensor_guards,
)
from dronefleet.schemas.codec import (
    decode_bundle_record,
    decode_link,
    decode_sensor,
    decode_status,
    decode_telemetry,
    encode,
)
from dronefleet.schemas.commands import Command, CommandReply, decode_command, new_command_id
from dronefleet.schemas.errors import CommandRejected, InvalidMessage
from dronefleet.schemas.fence import REASON as FENCE
from dronefleet.schemas.fleet import WatchEvent
from dronefleet.schemas.grounds import STALE_GROUND, ActiveGround, GroundInfo, NotCommanding, StandbyError
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.probe import ping_decoder
from dronefleet.schemas.status import CommandStatus
from dronefleet.schemas.telemetry import LinkQuality, SensorReading, Telemetry

log = logging.getLogger(__name__)
TICK_S = 0.2  # how often timeouts are checked: a drone goes unknown ≤ 200 ms late
WATCH_QUEUE = 2048
# A drone whose token comes back after it was lost has been routed anew: the ground's
# `ground/ping` queryable is declared afresh (at most this often), since the drone's
# router may hold no route to it while telemetry flows (ADR 0003, "ground/ping afresh").
PING_REFRESH_MIN_S = 2.0
# A drone heard this long with no route here to its commands is told so in the answer to
# its next probe, and declares them afresh (issue 76): a route usually follows a drone's
# first telemetry within a few tenths of a second.
REDECLARE_ASK_AFTER_MS = 500
ROUTE_RETRY_FIRST_S = 0.05  # a command to a heard drone with no route yet is asked again after this, doubling …
ROUTE_RETRY_MAX_S = 0.5  # … up to this, until the command deadline
_reply_decoder = msgspec.json.Decoder(CommandReply)
_bundle_reply_decoder = msgspec.json.Decoder(BundleReply)


class Watcher:
    """A bounded queue of WatchEvents; a watcher that falls behind loses the oldest."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[WatchEvent] = asyncio.Queue(WATCH_QUEUE)
        self.dropped = 0

    def put(self, event: WatchEvent) -> None:
        if self.queue.full():
            self.queue.get_nowait()
            self.dropped += 1
        self.queue.put_nowait(event)


class GroundStation:
    def __init__(self, config: GroundConfig, bus: Bus, events: EventLog, clock: Clock | None = None,
                 http_url: str = "", epoch_file: Path | None = None) -> None:
        self.config = config
        self.bus = bus
        self.events = events
        self.clock = clock or SystemClock()
        self.keys = Keys(config.namespace)
        self.inbound = Inbound(self.keys, self.clock)  # messages from the mesh, decoded (bad ones warned of)
        self.registry = Registry(config, relays_of(config.security))  # who the mesh lets relay
        self._watchers: set[Watcher] = set()
        self._watches_ended = False
        self._listeners: list[Callable[[WatchEvent], None]] = []
        self._last_telem_event: dict[str, float] = {}
        self.ping: Redeclarable | None = None  # `ground/ping`, the agents' probes: declared while running
        self._tokens_lost: set[str] = set()  # drones whose liveliness token went (refreshed when back)
        self._routes: dict[str, Declaration] = {}  # per drone heard: the watch on its command queryable's route
        self._ping_refreshed_at = -math.inf
        self.airspace = Airspace(config, self.registry)  # SPEC §11: the fence and the other drones' targets
        self.recordings: MissionRecordings | None = None
        self.signer = signer_of(config.security.pki_dir)  # SPEC §9: every command and bundle signed
        # Where command and bundle ids come from: random, or seeded in fast time (a
        # simulation replays to the byte, its recording included).
        self.new_command_id: Callable[[], str] = new_command_id
        self.new_bundle_id: Callable[[], str] = new_bundle_id
        self._held_bundle_statuses: dict[tuple[str, str], list[BundleStatus]] = {}
        self._catching_up: set[asyncio.Task[None]] = set()
        # About and field sensors (SPEC §2)
        self.feeds = SensorFeeds(bus, self.keys, self.clock, self.registry, self.inbound,
                                 query_timeout_s=config.command_timeout_ms / 1000, out=self)
        # SPEC §14: this ground among the grounds on the mesh; only the active one commands
        self.peers = GroundPeers(bus, self.keys, GroundInfo(ground_id=config.ground_id, priority=config.priority,
                                                            role=config.role, http=http_url),
                                 self.clock, on_change=self._role_changed, epoch_file=epoch_file,
                                 streams=self.stream_ends, on_active=self._heard_active)
        # SPEC §14: what the active ground records, kept by the others (more added by whoever owns them)
        self.copies: dict[str, tuple[StreamCopy, Callable[[], int]]] = {}
        # Taking over from a lost active ground (its id, and how far the missions' copy is
        # whole): whoever runs missions here goes on with its running ones.
        self.on_takeover: Callable[[str, int], object] = lambda origin, upto: None
        self.keep_copies("log", events.stream(), events.last_id, events)

    def record_missions(self, directory: Path, ground_station: tuple[float, float] | None = None) -> None:
        """Record each mission from now on to `<directory>/<id>.mcap` (SPEC §12)."""
        self.recordings = MissionRecordings(self.bus, self.keys, directory, now_ns_of(self.clock),
                                            self.config.geofence, ground_station)

    # ---- running -------------------------------------------------------------------

    async def run(self) -> None:
        """Listen to the mesh and keep time until cancelled."""
        k = self.keys
        declarations: list[Declaration] = [
            self.bus.subscribe(k.telem(), self._on_telemetry, latest_only=True, maxsize=8192),
            self.bus.subscribe(k.status(), self._on_status, maxsize=65_536),
            self.bus.subscribe(k.sensor(), self._on_sensor, latest_only=True, maxsize=8192),
            self.bus.subscribe(k.link(), self._on_link, latest_only=True, maxsize=8192),
            *self.feeds.declare(),
            self.bus.watch_liveliness(k.alive(), self._on_liveliness),
            self.bus.announce(k.ground_alive()),
            *self.peers.declare(),
            *(d for copy, _ in self.copies.values() for d in copy.declare()),
        ]
        self.ping = Redeclarable(self.bus, k.ground_ping(), self._answer_ping, self.clock)
        self.log_ground("info", "Ground station started")
        peers = asyncio.get_running_loop().create_task(self.peers.run(listen_first=bool(self.config.connect)),
                                                       name="ground peers")
        try:
            while True:
                self.emit(self.registry.tick(self.clock.time_ms()))
                self.feeds.tick()
                if self.recordings is not None:
                    self.recordings.tick()
                await self.clock.sleep(TICK_S)
        finally:
            peers.cancel()
            self.peers.close()
            self.ping.close()
            for route in self._routes.values():
                route.close()
            for copy, _ in self.copies.values():
                copy.close()
            self.log_ground("info", "Ground station stopped")
            if self.recordings is not None:
                self.recordings.close()
            for declaration in reversed(declarations):
                declaration.close()

    def keep_copies(self, name: str, stream: Stream, last: Callable[[], int], source: Any) -> None:
        """Another numbered record this ground keeps (`source.on_change(seq, entry)` tells
        of each new entry), copied by the others like its event log: before `run`."""
        copy = StreamCopy(self.bus, self.keys, self.config.ground_id, stream)
        self.copies[name] = (copy, last)
        source.on_change = lambda seq, entry: copy.published(seq, entry) if self.peers.active else None

    def stream_ends(self) -> dict[str, int]:
        """Where each record this ground keeps numbered ends (its announcement carries them)."""
        return {name: last() for name, (_, last) in self.copies.items()}

    def _heard_active(self, said: ActiveGround) -> None:
        for name, (copy, _) in self.copies.items():
            copy.heard_active(said.ground_id, said.streams.get(name, 0))

    def _role_changed(self, change: Change) -> None:
        me = self.config.ground_id
        if change.state == "active":
            self.log_ground("info", f"Ground {me} is active (epoch {change.epoch}): {change.why}")
            if change.taken_from is not None:
                copy = self.copies.get("missions")
                self.on_takeover(change.taken_from, copy[0].upto(change.taken_from) if copy is not None else 0)
        else:
            active = self.peers.active_ground()
            self.log_ground("warn", f"Ground {me} is standby ({active.ground_id if active else 'no ground'} "
                                    f"is active): {change.why}")

    def standby(self) -> StandbyError | None:
        """None while this ground is active; else SPEC §14's refusal, naming who is."""
        if self.peers.active:
            return None
        active = self.peers.active_ground()
        return StandbyError(error="observer" if self.config.role == "observer" else "standby",
                            active=active.ground_id if active else "", http=active.http if active else "")

    def check_commanding(self) -> None:
        """NotCommanding (503, 403 on an observer) unless this ground commands now (SPEC §14)."""
        refusal = self.standby()
        if refusal is not None:
            raise NotCommanding(refusal)

    def log_ground(self, level: str, message: str) -> None:
        """A line about the ground itself (no drone)."""
        self.emit([LogLine(timestamp=self.clock.time_ms(), level=level, drone_id=None, message=message)])  # type: ignore[arg-type]

    @contextmanager
    def watch(self) -> Iterator[Watcher]:
        watcher = Watcher()
        if self._watches_ended:  # a stream that starts while the ground stops ends at once
            watcher.put(WatchEvent("end", None))
        self._watchers.add(watcher)
        try:
            yield watcher
        finally:
            self._watchers.discard(watcher)

    def listen(self, listener: Callable[[WatchEvent], None]) -> Callable[[], None]:
        """Call `listener` synchronously with every telemetry (unthrottled), status and
        drone change (missions); returns the function that stops it."""
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener) if listener in self._listeners else None

    def tell(self, event: WatchEvent) -> None:
        for listener in list(self._listeners):
            listener(event)

    async def assign(self, drone_id: str, mission_id: str) -> None:
        """Claim a drone for a mission; 404 if unknown, 409 if another mission holds it."""
        self._registered(drone_id)
        holder = self.registry.info(drone_id).mission
        if holder not in (None, mission_id):
            raise CommandRejected(409, f"{drone_id} is assigned to mission {holder}")
        self.emit(self.registry.assign(drone_id, mission_id, self.clock.time_ms()))

    def release(self, drone_id: str) -> None:
        if drone_id in self.registry:
            self.emit(self.registry.release(drone_id, self.clock.time_ms()))

    # ---- commands ------------------------------------------------------------------

    async def command(self, drone_id: str, body: bytes, mission_id: str | None = None, *, who: str | None = None) -> CommandReply:
        """Validate, check and forward one command (SPEC §4 POST /drone/{id}/cmd).

        Raises InvalidMessage (400), CommandRejected (404/409; 503 on a standby ground)
        or bus Unreachable (504).
        """
        self.check_commanding()
        self._registered(drone_id)
        command = self._stamp(drone_id, body)
        self._check(drone_id, command.name, command.name, mission_id)
        spot = self.airspace.check(drone_id, command)
        if isinstance(spot, CommandRejected):
            self._refuse(drone_id, command.name, spot)
        self._audit(drone_id, f"{command.name} (command {command.command_id})", who)
        self.airspace.sent(drone_id, command, spot)
        try:
            reply: CommandReply = await self._deliver_as_active(self.keys.cmd(drone_id), command, _reply_decoder,
                                                                "CommandReply")
        except BaseException:
            if spot is not None:
                self.airspace.undo(drone_id, command.command_id)
            raise
        return reply

    async def push(self, drone_id: str, body: bytes, mission_id: str | None = None, *, who: str | None = None) -> BundleReply:
        """Validate, check and send one task bundle (SPEC §6; POST /drone/{id}/bundle).

        The whole bundle is checked here first (400 naming the step and field), then
        by the agent. Raises InvalidMessage, CommandRejected (404/409/503) or Unreachable.
        """
        self.check_commanding()
        self._registered(drone_id)
        obj = self._body(drone_id, body)
        obj.update(ground_epoch=self.peers.epoch, ground_id=self.config.ground_id)
        obj.setdefault("bundle_id", "")
        if not obj["bundle_id"]:
            obj["bundle_id"] = self.new_bundle_id()
        bundle = parse_bundle(json.dumps(obj).encode())
        self._check_sensor_guards(drone_id, bundle.wire)
        self._check(drone_id, "bundle", f"bundle {bundle.bundle_id}", mission_id)
        self._audit(drone_id, f"bundle {bundle.bundle_id}", who)
        # Noted before sending: the agent's first status may arrive before its reply.
        self.registry.note_bundle(drone_id, bundle.bundle_id, [describe_step(step) for step in bundle.steps])
        try:
            reply: BundleReply = await self._deliver_as_active(self.keys.bundle(drone_id), bundle.wire,
                                                               _bundle_reply_decoder, "BundleReply")
        except BaseException:
            self.registry.forget_bundle(drone_id, bundle.bundle_id)
            raise
        return reply

    async def bundle_record(self, drone_id: str, bundle_id: str) -> BundleRecord:
        """What the agent did with a bundle (SPEC §6): asked of the agent itself, so a
        ground that was out of range catches up. Raises CommandRejected 404 or Unreachable."""
        self._registered(drone_id)
        try:
            # a read: asked again while no route reaches the agent, as a command is
            raw = await self._query_within(f"{self.keys.bundle(drone_id)}?id={bundle_id}", b"",
                                           self.config.command_timeout_ms / 1000)
        except QueryRefused as exc:
            raise CommandRejected(404, str(exc).split(": ", 1)[-1]) from None
        try:
            record = decode_bundle_record(raw)
        except InvalidMessage as exc:
            raise CommandRejected(502, f"the agent answered something that is not a bundle record: {exc}") from None
        self.emit(self.registry.on_bundle_record(record, drone_id, self.clock.time_ms()))
        return record

    def _check_sensor_guards(self, drone_id: str, wire: Any) -> None:
        """Every `sensor.<type>[.<field>]` a bundle's guards read: a sensor the drone
        carries, and (declared with fields) a field it declares."""
        info = self.registry.info(drone_id)
        carried, declared = info.sensors, {d.type: d for d in info.sensors_declared or []}
        for path, label, name in sensor_guards(wire):
            kind, _, field = name.partition(".")
            if kind not in carried:
                raise InvalidMessage(f"{label}: {drone_id} carries no {kind} sensor (it has: {', '.join(carried) or 'none'})", field=path)
            decl = declared.get(kind)
            if decl is not None and decl.fields and field not in decl.fields:
                fields = ", ".join(f"sensor.{kind}.{f}" for f in sorted(decl.fields))
                raise InvalidMessage(f"{label}: {drone_id}'s {kind} sensor has fields {fields}", field=path)
            if decl is not None and not decl.fields and field:
                raise InvalidMessage(f"{label}: {drone_id}'s {kind} sensor has one value (sensor.{kind}), no fields", field=path)

    def _audit(self, drone_id: str, what: str, who: str | None) -> None:
        """SPEC §9: who sent it, in the event log (when the API knows: tokens are on)."""
        if who is not None:
            self.emit([LogLine(timestamp=self.clock.time_ms(), level="info", drone_id=drone_id, message=f"{what} sent by {who}")])

    def _registered(self, drone_id: str) -> None:
        if drone_id not in self.registry:
            raise CommandRejected(404, f"no drone {drone_id!r} is registered")

    def _check(self, drone_id: str, name: str, label: str, mission_id: str | None) -> None:
        """The registry's refusal of `name` now (thesis §4.2.4)."""
        refusal = self.registry.check_command(drone_id, name, mission_id)
        if refusal is not None:
            self._refuse(drone_id, label, CommandRejected(refusal.status, refusal.reason, refusal.code))

    def _refuse(self, drone_id: str, label: str, rejected: CommandRejected) -> NoReturn:
        """Log the refusal as "Refused <label>: …" and raise it."""
        self.emit([LogLine(timestamp=self.clock.time_ms(), level="warn", drone_id=drone_id,
                           message=f"Refused {label}: {rejected.reason}")])
        raise rejected

    def _signed(self, message: T) -> T:
        return message if self.signer is None else self.signer.sign(message, self.clock.time_ms())

    async def _deliver_as_active(self, key: str, message: Command | TaskBundle, decoder: msgspec.json.Decoder[Any],
                                 kind: str) -> Any:
        """`_deliver`, and once more if the agent held a newer epoch than ours and this
        ground, still chosen, took one above it (a ground whose data dir was lost)."""
        try:
            return await self._deliver(key, encode(self._signed(message)), decoder, kind)
        except CommandRejected as exc:
            if exc.code != STALE_GROUND or not self.peers.active or self.peers.epoch <= message.ground_epoch:
                raise
        again = msgspec.structs.replace(message, ground_epoch=self.peers.epoch)
        return await self._deliver(key, encode(self._signed(again)), decoder, kind)

    async def _deliver(self, key: str, payload: bytes, decoder: msgspec.json.Decoder[Any], kind: str) -> Any:
        """Query the agent's queryable and hold it to its reply (`accepted`, `reason`)."""
        if self.recordings is not None:
            self.recordings.sent(key, payload)
        raw = await self._query_within(key, payload, self.config.command_timeout_ms / 1000)
        try:
            reply = decoder.decode(raw)
        except msgspec.MsgspecError as exc:
            raise CommandRejected(502, f"the agent answered something that is not a {kind}: {exc}") from None
        if not reply.accepted:
            reason = reply.reason or "refused by the agent"
            if reason == STALE_GROUND and reply.ground_epoch:  # a newer epoch than ours is in use: learn it
                self.peers.heard_epoch(reply.ground_epoch, key.split("/")[-2])
                raise CommandRejected(409, f"{STALE_GROUND}: the agent holds epoch {reply.ground_epoch}",
                                      code=STALE_GROUND)
            raise CommandRejected(409, reason, code=FENCE if reason.startswith(FENCE) else None)
        return reply

    async def _query_within(self, key: str, payload: bytes, deadline_s: float) -> bytes:
        """The agent's reply within `deadline_s`. A drone the ground hears but whose
        queryable has not reached this router yet (one that registered a moment ago
        through a neighbour: its telemetry came first) is asked again, sooner at first,
        until the deadline: no query reached it, so asking again sends nothing twice.
        Only then NoRoute, saying how long it was tried."""
        start = self.clock.monotonic()
        pause_s = ROUTE_RETRY_FIRST_S
        while True:
            left_s = deadline_s - (self.clock.monotonic() - start)
            try:
                return await self.bus.query(key, payload, timeout_s=max(left_s, ROUTE_RETRY_FIRST_S))
            except NoRoute:
                if left_s <= pause_s:
                    raise NoRoute(self._no_route(key, deadline_s)) from None
            await self.clock.sleep(pause_s)
            pause_s = min(pause_s * 2, ROUTE_RETRY_MAX_S)

    def _no_route(self, key: str, deadline_s: float) -> str:
        parsed = self.keys.parse(key)
        unrouted_ms = self.registry.unrouted_for_ms(parsed.drone_id, self.clock.time_ms()) if parsed else None
        why = (f"the drone is heard, but this ground has held no route to its commands for {unrouted_ms / 1000:.1f} s "
               "(its agent is asked to declare them afresh)" if unrouted_ms is not None
               else "the drone is heard, its commands are not")
        return f"no route to {key} within {deadline_s:g} s: its agent's queryable has not reached the ground ({why})"

    def _body(self, drone_id: str, body: bytes) -> dict[str, Any]:
        """A JSON object body for `drone_id`, with drone_id and timestamp set."""
        try:
            obj = msgspec.json.decode(body)
        except msgspec.DecodeError:
            try:  # NaN/Infinity tokens: the decoder then names the field
                obj = json.loads(body)
            except (ValueError, UnicodeDecodeError) as exc:
                raise InvalidMessage(f"malformed JSON: {exc}") from None
        if not isinstance(obj, dict):
            raise InvalidMessage(f"the body must be a JSON object, got {type(obj).__name__}", field="$")
        if obj.get("drone_id", drone_id) != drone_id:
            raise InvalidMessage(f"drone_id: the path names {drone_id!r}, the body {obj['drone_id']!r}", field="$.drone_id")
        obj.update(drone_id=drone_id, timestamp=self.clock.time_ms())
        return obj

    def _stamp(self, drone_id: str, body: bytes) -> Command:
        """The request body plus drone_id, timestamp and (unless given) command_id."""
        obj = self._body(drone_id, body)
        if not obj.get("command_id"):
            obj["command_id"] = self.new_command_id()
        # SPEC §14: agents refuse an epoch older than they heard, or one another ground holds
        obj.update(ground_epoch=self.peers.epoch, ground_id=self.config.ground_id)
        return decode_command(json.dumps(obj))

    # ---- events in -----------------------------------------------------------------

    def _on_telemetry(self, sample: Sample) -> None:
        telem: Telemetry | None = self.inbound.from_drone(decode_telemetry, sample)
        if telem is not None:
            now_ms = self.clock.time_ms()
            if telem.drone_id not in self._routes and self.registry.admits(telem.drone_id, now_ms):
                self._watch_route(telem.drone_id)
            self.emit(self.registry.on_telemetry(telem, now_ms))
            self.feeds.ask_about(telem.drone_id)  # what it is (one not registered for want of it may then be)
            if telem.drone_id not in self.registry:  # full, or past the unannounced bucket: counted there
                return
            self._offer_telemetry(telem)
            self.tell(WatchEvent("telemetry", telem))

    def _watch_route(self, drone_id: str) -> None:
        """From the drone's first telemetry on: whether this router holds a route to its
        command queryable. Heard without one, it is `unreachable`, not `ready` (issue 76)."""
        def routed(ok: bool) -> None:
            self.emit(self.registry.on_route(drone_id, ok, self.clock.time_ms()))

        self._routes[drone_id] = self.bus.watch_route(self.keys.cmd(drone_id), routed)

    async def _answer_ping(self, key: str, payload: bytes) -> bytes:
        """A probe, echoed (SPEC §8). To a drone heard here for a while with no route to
        its commands, the echo asks it to declare them afresh: the answer goes back the
        way the probe came, which needs no declaration (ADR 0003)."""
        try:
            ping = ping_decoder.decode(payload)
        except msgspec.MsgspecError:
            return payload
        unrouted_ms = self.registry.unrouted_for_ms(ping.drone_id, self.clock.time_ms())
        if unrouted_ms is None or unrouted_ms < REDECLARE_ASK_AFTER_MS:
            return payload
        return encode(msgspec.structs.replace(ping, redeclare=True))

    def _on_status(self, sample: Sample) -> None:
        status = self.inbound.decode(decode_status, sample)
        if status is None:
            return
        parsed = self.keys.parse(sample.key)
        if parsed is None or status.drone_id != parsed.drone_id:
            # A status speaks for the drone whose key it came on, and only for it: one
            # naming another drone would move that drone's commands and bundles.
            self.inbound.warnings.warn(sample.key, "ignored a status on %s that names drone %r", sample.key, status.drone_id)
            return
        if not self.registry.first_heard(status):
            return
        if isinstance(status, CommandStatus):
            self.airspace.on_status(status)
        event = WatchEvent("status", status)
        self.broadcast(event)
        if isinstance(status, BundleStatus) and self.registry.bundle_gap(status):
            self._log_after_catch_up(status)
        else:
            self.emit(self.registry.on_status(status, self.clock.time_ms()))
        self.tell(event)  # after the registry: missions see the drone as it now is

    def _log_after_catch_up(self, status: BundleStatus) -> None:
        """Events of this bundle were lost on the way (the drone was out of reach, and
        its bundle went on): read the bundle's record from the agent first, so the log
        tells the bundle in order, then this status (already in the record unless the
        read fails; the registry logs each event once)."""
        key = (status.drone_id, status.bundle_id)
        if key in self._held_bundle_statuses:  # a read is under way: after it
            self._held_bundle_statuses[key].append(status)
            return
        self._held_bundle_statuses[key] = [status]

        async def catch_up() -> None:
            try:
                await self.bundle_record(*key)
            except (CommandRejected, Unreachable) as exc:
                log.info("%s: could not read bundle %s to catch up: %s", status.drone_id, status.bundle_id, exc)
            finally:
                for held in self._held_bundle_statuses.pop(key, []):
                    self.emit(self.registry.on_status(held, self.clock.time_ms()))

        task = asyncio.get_running_loop().create_task(catch_up(), name=f"catch up {status.drone_id} {status.bundle_id}")
        self._catching_up.add(task)
        task.add_done_callback(self._catching_up.discard)

    def _on_sensor(self, sample: Sample) -> None:
        reading: SensorReading | None = self.inbound.from_drone(decode_sensor, sample)
        if reading is not None:
            dropped = self.registry.drop_reading(reading, self.clock.time_ms())
            if dropped is not None:  # outside what the drone declared: logged, never shown as a value
                self.emit(dropped)
                return
            self.emit(self.registry.on_sensor(reading, self.clock.time_ms()))
            self.tell(WatchEvent("sensor", reading))  # a mission in its own process keeps a copy

    def _on_link(self, sample: Sample) -> None:
        quality: LinkQuality | None = self.inbound.from_drone(decode_link, sample)
        if quality is not None:
            self.emit(self.registry.on_link(quality, self.clock.time_ms()))

    def _on_liveliness(self, key: str, alive: bool) -> None:
        parsed = self.keys.parse(key)
        if parsed is None:
            return
        if not alive:
            self._tokens_lost.add(parsed.drone_id)
        elif parsed.drone_id in self._tokens_lost:
            self._tokens_lost.discard(parsed.drone_id)
            self._refresh_ping(parsed.drone_id)
        self.emit(self.registry.on_liveliness(parsed.drone_id, alive, self.clock.time_ms()))

    def _refresh_ping(self, drone_id: str) -> None:
        """A drone routed anew may not reach `ground/ping` again: routers carry a
        declaration along the declarer's tree when it changes, and after a link closed
        and came back a drone's router was seen with no route to it for minutes while
        its telemetry flowed (upstream #2767's kind). Its probes then went unanswered, so
        it took the ground for lost: a failsafe, and the statuses it holds for the ground
        never repeated (a mission waited for a landing that had happened). Declared afresh
        in the other form (bus/redeclarable.py), the declaration travels the mesh again."""
        now = self.clock.monotonic()
        if now - self._ping_refreshed_at < PING_REFRESH_MIN_S or self.ping is None:
            return
        self._ping_refreshed_at = now
        self.ping.refresh()
        log.info("%s is back on the mesh: ground/ping declared afresh (%s)", drone_id, self.ping.form)

    # ---- events out ----------------------------------------------------------------

    def emit(self, events: list[Event]) -> None:
        for event in events:
            if isinstance(event, LogLine):
                row = self.events.append(event)  # published to the standby grounds while active (keep_copies)
                log.log(_LOG_LEVELS[event.level], "%s - %s", event.drone_id or "ground", event.message)
                self.broadcast(WatchEvent("log", event, row))
            elif isinstance(event, InfoChanged):
                changed = WatchEvent("drone", event.info)
                self.broadcast(changed)
                self.tell(changed)

    def end_watches(self) -> None:
        """Tell every watcher the ground is stopping (event streams then close), also
        those that register from now on (a request already accepted by the server)."""
        self._watches_ended = True
        self.broadcast(WatchEvent("end", None))

    def _offer_telemetry(self, telem: Telemetry) -> None:
        """Telemetry reaches watchers at most once per `event_telemetry_ms` per drone."""
        if not self._watchers:
            return
        now = self.clock.monotonic()
        if now - self._last_telem_event.get(telem.drone_id, -1e9) >= self.config.event_telemetry_ms / 1000:
            self._last_telem_event[telem.drone_id] = now
            self.broadcast(WatchEvent("telemetry", telem))

    def broadcast(self, event: WatchEvent) -> None:
        if self.recordings is not None:
            self.recordings.on_event(event)
        for watcher in self._watchers:
            watcher.put(event)


_LOG_LEVELS = {"info": logging.INFO, "warn": logging.WARNING, "error": logging.ERROR}
