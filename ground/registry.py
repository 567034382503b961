"""The fleet registry: what the ground knows of every drone, derived from events.

Pure logic (thesis §4.2.4–4.2.7): feed it telemetry, statuses, sensor readings,
liveliness changes and the time, and it keeps per drone the telemetry as received
plus the derived `info` (state, current command, errors, warns, sensors, mission).
Every method returns what happened as events — log lines for the event log and
`InfoChanged` for whoever watches (the dashboard stream, missions) — and never
reads a clock or touches I/O, so the whole table is tested without an event loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec

from dronefleet.ground.config import GroundConfig
from dronefleet.ground.describe import Described, Level, bundle_line, describe_start, status_line, system_line
from dronefleet.ground.field_sensor_registry import FieldSensors
from dronefleet.schemas.about import About, reading_fault, relay_disagreement
from dronefleet.schemas.bundles import BundleRecord, BundleStatus
from dronefleet.schemas.errors import STATE_UNKNOWN
from dronefleet.schemas.fleet import (
    COMMANDS_REACH,
    COMMANDS_UNREACHABLE,
    CRITICAL_BATTERY,
    FC_DISCONNECTED,
    HEALTH_FAILING,
    HEALTH_PREFIX,
    LINK_DEGRADED,
    LINK_LOST,
    LINK_RESTORED,
    LOW_BATTERY,
    BundleInfo,
    CurrentCommand,
    DroneInfo,
    DroneState,
)
from dronefleet.schemas.status import CommandStatus, SystemStatus
from dronefleet.schemas.telemetry import GROUND_PEER, MANUAL_MODES, LinkQuality, SensorReading, Telemetry


class LogLine(msgspec.Struct, frozen=True, kw_only=True):
    timestamp: int  # ms since the epoch
    level: Level
    drone_id: str | None
    message: str


class InfoChanged(msgspec.Struct, frozen=True, kw_only=True):
    info: DroneInfo


Event = LogLine | InfoChanged


class Refusal(msgspec.Struct, frozen=True, kw_only=True):
    status: int  # the HTTP status it maps to: 404 unknown drone, 409 cannot now
    reason: str
    code: str | None = None  # CommandRejected.code


DROPPED_LOG_MS = 30_000  # a sensor whose readings keep falling outside its declaration: one line per this
STATUSES_REMEMBERED = 128  # per drone: command statuses heard (an agent repeats those the ground may have missed)
BUNDLES_REMEMBERED = 16  # per drone: which events of its latest bundles the ground heard


@dataclass
class _Sensor:
    reading: SensorReading
    received_ms: int


COMMANDS_KEPT = 32  # command statuses kept per drone (Registry.command_statuses)

TURNED_AWAY_EVERY_MS = 10_000  # a full registry says how many ids it turned away at most this often
# New ids whose About was not heard register on their first telemetry (SPEC §3) from a
# bucket of this many, refilled at ground.unannounced_per_s: a real drone says what it is
# before or with its first sample, made-up ids on an open mesh mostly never do.
UNANNOUNCED_BURST = 64
TURNED_AWAY_COUNTED = 100_000  # distinct ids counted per line, at most (the count itself is bounded)
# Abouts of ids not registered (yet): kept for their registration, the newest this many.
ABOUTS_UNREGISTERED_KEPT = 4096
# A drone heard this long with no route to its commands is logged so: a route usually
# follows its first telemetry within a few tenths of a second.
UNREACHABLE_TOLD_AFTER_MS = 1000


@dataclass
class _Drone:
    drone_id: str
    telem: Telemetry
    last_telem_ms: int
    unknown: bool = False
    alive: bool | None = None  # None: never saw a liveliness token
    token_lost_ms: int = 0  # when its liveliness token went, to tell late samples from a live session
    fc_disconnected: bool = False
    current: CurrentCommand | None = None
    described: dict[str, Described] = field(default_factory=dict)  # command_id → how to name it
    sensors: dict[str, _Sensor] = field(default_factory=dict)
    mission: str | None = None
    link: LinkQuality | None = None
    bundle: BundleInfo | None = None
    bundle_steps: dict[str, list[str]] = field(default_factory=dict)  # bundle id → step descriptions (pushed here)
    bundle_heard: dict[str, set[tuple[int, str]]] = field(default_factory=dict)  # bundle id → (step, state) heard
    status_heard: dict[tuple[object, ...], None] = field(default_factory=dict)  # (command id, state) or a bundle event, oldest first
    info: DroneInfo | None = None
    commands: list[CommandStatus] = field(default_factory=list)  # its latest command statuses, oldest first
    dropping: dict[str, tuple[int, int]] = field(default_factory=dict)  # sensor type → (logged at ms, dropped since)
    health_failing_since_ms: int | None = None  # the first sample of the current run of failing health checks
    unrouted_since_ms: int | None = None  # heard, but no route here to its command queryable since (None: routed)
    unreachable_told: bool = False  # the log says so


def describe_about(about: About) -> str:
    """`kind x500, roles survey, relay, sensors gas (co_ppm ppm 0–1000)`."""
    sensors = []
    for decl in about.sensors:
        parts = [f"{name} {spec.unit}".strip() for name, spec in decl.fields.items()] or ([decl.unit] if decl.unit else [])
        sensors.append(f"{decl.type} ({', '.join(parts)})" if parts else decl.type)
    return f"kind {about.kind}, roles {', '.join(about.roles)}, sensors {', '.join(sensors) or 'none declared'}"


# Telemetry heard this long after a drone's liveliness token went is a live session
# whose token did not come back, not a late sample of a dead one.
TOKEN_LATE_MS = 1000


class Registry:
    def __init__(self, config: GroundConfig, relays: frozenset[str] | None = None) -> None:
        self.config = config
        self._drones: dict[str, _Drone] = {}
        self._abouts: dict[str, About] = {}  # heard per drone, also before its first telemetry
        self._unregistered_abouts: dict[str, None] = {}  # of those, the ids not registered, oldest first
        self._routed: dict[str, bool] = {}  # whether its command queryable is routed here, also before registering
        self._turned_away: set[str] = set()  # ids heard past max_drones since the last line said so
        self._turned_away_told_ms = -TURNED_AWAY_EVERY_MS
        self._unannounced: set[str] = set()  # new ids without an About past the bucket, since the last line
        self._unannounced_told_ms = -TURNED_AWAY_EVERY_MS
        self._bucket = float(UNANNOUNCED_BURST)  # unannounced registrations it may make now
        self._bucket_ms: int | None = None
        self.field = FieldSensors(config.sensor_timeout_ms)  # sensors that are not on a drone (SPEC §2)
        self.relays = relays  # on a secured mesh, the drones that may relay; None: every drone

    # ---- queries -------------------------------------------------------------------

    def __contains__(self, drone_id: str) -> bool:
        return drone_id in self._drones

    def admits(self, drone_id: str, now_ms: int | None = None) -> bool:
        """Whether telemetry under this id is taken (at `now_ms`, if given): a registered
        drone, or room for one (and for a drone whose About was not heard, a registration
        left in the bucket)."""
        if drone_id in self._drones:
            return True
        if now_ms is not None:
            self._refill(now_ms)
        return len(self._drones) < self.config.max_drones and (drone_id in self._abouts or self._bucket >= 1)

    def _refill(self, now_ms: int) -> None:
        if self._bucket_ms is not None:
            self._bucket = min(float(UNANNOUNCED_BURST),
                               self._bucket + max(0, now_ms - self._bucket_ms) / 1000 * self.config.unannounced_per_s)
        self._bucket_ms = now_ms

    def ids(self) -> list[str]:
        return sorted(self._drones)

    def info(self, drone_id: str) -> DroneInfo:
        d = self._drones[drone_id]
        assert d.info is not None
        return d.info

    def telemetry(self, drone_id: str) -> Telemetry:
        return self._drones[drone_id].telem

    def sensor_readings(self, drone_id: str) -> list[SensorReading]:
        d = self._drones[drone_id]
        return [d.sensors[t].reading for t in sorted(d.sensors)]

    def command_statuses(self, drone_id: str) -> list[CommandStatus]:
        """Its last COMMANDS_KEPT command statuses, oldest first: what a mission taken over
        may have missed while no ground was active (mission.hosting.isolation)."""
        return list(self._drones[drone_id].commands)

    def select(self, state: str | None = None, sensors: list[str] | None = None) -> list[str]:
        """Ids of the drones in `state` (if given) carrying every sensor type listed."""
        return [
            i for i in self.ids()
            if (state is None or self.info(i).state == state)
            and all(s in self._drones[i].sensors for s in sensors or [])
        ]

    def check_command(self, drone_id: str, cmd: str, mission_id: str | None = None) -> Refusal | None:
        """Why the ground refuses `cmd` for this drone now, or None (thesis §4.2.4).
        `return` always goes through: it is the way home whatever else is wrong."""
        d = self._drones.get(drone_id)
        if d is None:
            return Refusal(status=404, reason=f"no drone {drone_id!r} is registered")
        if cmd == "return":
            return None
        info = self.info(drone_id)
        if info.state == "unknown":
            return Refusal(status=409, reason="drone state is unknown: no recent telemetry", code=STATE_UNKNOWN)
        if info.state == "error":
            return Refusal(status=409, reason=f"drone is in error: {'; '.join(info.errors)}")
        if info.state == "manual":
            return Refusal(status=409, reason="drone is under manual control")
        if d.mission is not None and d.mission != mission_id:
            return Refusal(status=409, reason=f"drone is assigned to mission {d.mission}")
        if mission_id is not None and d.mission != mission_id:
            return Refusal(status=409, reason=f"drone is not assigned to mission {mission_id}")
        return None

    # ---- events in -----------------------------------------------------------------

    def on_telemetry(self, telem: Telemetry, now_ms: int) -> list[Event]:
        out: list[Event] = []
        d = self._drones.get(telem.drone_id)
        if d is None:
            self._refill(now_ms)
            if not self.admits(telem.drone_id):
                full = len(self._drones) >= self.config.max_drones
                counted = self._turned_away if full else self._unannounced
                if len(counted) < TURNED_AWAY_COUNTED:
                    counted.add(telem.drone_id)
                return []
            if telem.drone_id not in self._abouts:
                self._bucket -= 1
            d = self._drones[telem.drone_id] = _Drone(telem.drone_id, telem, now_ms)
            self._unregistered_abouts.pop(telem.drone_id, None)
            out.append(self._line(now_ms, "info", d, "Registered"))
            if not self._routed.get(d.drone_id, False):
                d.unrouted_since_ms = now_ms
            if d.drone_id in self._abouts:
                out += self._about_lines(d, None, now_ms)
            before_errors: list[str] = []
            before_warns: list[str] = []
            reconnected = first = True
        else:
            assert d.info is not None
            before_errors, before_warns = d.info.errors, d.info.warns
            if d.alive is False:
                if now_ms - d.token_lost_ms <= TOKEN_LATE_MS:
                    return out  # late samples of a session whose token is gone
                # Still heard well after its token went: the session lives and the token
                # did not come back (a router's token table after a link closed and
                # reopened, ADR 0003). Telemetry is the truth; silence still times out.
                d.alive = None
                out.append(self._line(now_ms, "info", d, "Heard again without its liveliness token: "
                                      "telemetry decides its link until the token is back"))
            reconnected, first = d.unknown, False
            d.telem, d.last_telem_ms, d.unknown = telem, now_ms, False
            if reconnected and d.unrouted_since_ms is not None:  # heard again: unreachable counts from now
                d.unrouted_since_ms = now_ms
            if d.current is not None and d.current.command in ("return", "land") \
                    and telem.landed_state == "on_ground" and not telem.armed:
                # Landed and disarmed: that return or landing is over, also when its end
                # was sent out of radio range and never heard here.
                out.append(self._line(now_ms, "info", d, f"Finish {d.current.description.lower()} (landed)"))
                d.current = None
        if not telem.health_failures:
            d.health_failing_since_ms = None
        elif d.health_failing_since_ms is None:
            d.health_failing_since_ms = now_ms
        info = self._derive(d)
        for message in info.errors:
            if message not in before_errors:
                out.append(self._line(now_ms, "error", d, message))
        for message in info.warns:
            if message not in before_warns and message not in (FC_DISCONNECTED, LINK_DEGRADED):
                out.append(self._line(now_ms, "warn", d, message))
        if reconnected:
            message = "Established connection with ground station" if first else f"{LINK_RESTORED}: established connection with ground station"
            out.append(self._line(now_ms, "info", d, message))
        if before_errors and not info.errors:
            out.append(self._line(now_ms, "info", d, "Errors cleared"))
        return out + self._publish(d, info)

    def note_bundle(self, drone_id: str, bundle_id: str, descriptions: list[str]) -> None:
        """A bundle the ground sent: its steps, to describe them as they start."""
        d = self._drones.get(drone_id)
        if d is not None:
            d.bundle_steps[bundle_id] = descriptions

    def forget_bundle(self, drone_id: str, bundle_id: str) -> None:
        """A noted bundle that never reached the drone."""
        d = self._drones.get(drone_id)
        if d is not None:
            d.bundle_steps.pop(bundle_id, None)

    def first_heard(self, status: CommandStatus | SystemStatus | BundleStatus) -> bool:
        """False for a command or bundle status heard before: an agent repeats the
        statuses the ground may have missed when its probes went unanswered (a repeat is
        the same status, timestamp and all)."""
        d = self._drones.get(status.drone_id)
        heard: tuple[object, ...]
        if d is None or isinstance(status, SystemStatus):
            return True
        if isinstance(status, BundleStatus):
            heard = (status.bundle_id, status.step, status.state, status.scope, status.timestamp)
        elif not status.command_id:
            return True
        else:
            heard = (status.command_id, status.state)
        if heard in d.status_heard:
            return False
        d.status_heard[heard] = None
        while len(d.status_heard) > STATUSES_REMEMBERED:
            del d.status_heard[next(iter(d.status_heard))]
        return True

    def on_status(self, status: CommandStatus | SystemStatus | BundleStatus, now_ms: int) -> list[Event]:
        d = self._drones.get(status.drone_id)
        if d is None:
            return []  # registration happens on telemetry; the agent repeats nothing we need
        if isinstance(status, BundleStatus):
            return self._on_bundle(d, status, now_ms)
        if isinstance(status, SystemStatus):
            if status.state == "disconnect":
                d.fc_disconnected = True
            elif status.state == "connect":
                d.fc_disconnected = False
            level, message = system_line(status)
            return [self._line(now_ms, level, d, message), *self._publish(d, self._derive(d))]
        d.commands.append(status)
        del d.commands[:-COMMANDS_KEPT]
        if status.state in ("start", "queued"):
            d.described[status.command_id] = describe_start(status)
        described = d.described.get(status.command_id) or describe_start(status)
        if status.state == "start":
            d.current = CurrentCommand(
                description=described.current, timestamp=now_ms,
                command=status.command, command_id=status.command_id,
                coords=status.coords, altitude=status.altitude,
            )
        elif status.state in ("finish", "cancel", "stop", "failure", "success"):
            d.described.pop(status.command_id, None)
            if d.current is not None and d.current.command_id == status.command_id:
                d.current = None
        level, message = status_line(status, described)
        return [self._line(now_ms, level, d, message), *self._publish(d, self._derive(d))]

    def on_bundle_record(self, record: BundleRecord, drone_id: str, now_ms: int) -> list[Event]:
        """Catch up with a bundle record read from the agent: the events it published
        while out of reach are logged now (and `info.bundle` follows them), once."""
        d = self._drones.get(drone_id)
        if d is None:
            return []
        heard = d.bundle_heard.get(record.bundle_id, set())
        missed = [e for e in record.history if (e.step, e.state) not in heard]
        if not missed:
            return []
        out: list[Event] = [self._line(now_ms, "info", d, f"Bundle {record.bundle_id}: caught up on {len(missed)} "
                                       f"event{'s' if len(missed) != 1 else ''} sent while out of reach")]
        for e in missed:
            out += self._on_bundle(d, BundleStatus(drone_id=drone_id, timestamp=e.timestamp, bundle_id=record.bundle_id,
                                                   step=e.step, state=e.state, reason=e.reason, scope=e.scope,
                                                   steps=record.steps), now_ms)
        return out

    def bundle_gap(self, status: BundleStatus) -> bool:
        """Whether an earlier event of this bundle never arrived (sent while the drone was
        out of reach): a step before it, or its own step, was never heard to start."""
        d = self._drones.get(status.drone_id)
        if d is None:
            return False
        heard = d.bundle_heard.get(status.bundle_id, set())
        if (status.step, status.state) in heard:
            return False
        started = status.step if status.state == "start" else status.step + 1
        return any((step, "start") not in heard for step in range(started))

    def _on_bundle(self, d: _Drone, status: BundleStatus, now_ms: int) -> list[Event]:
        heard = d.bundle_heard.setdefault(status.bundle_id, set())
        if (status.step, status.state) in heard:
            return []  # already caught up from the record (it overtook this status)
        heard.add((status.step, status.state))
        while len(d.bundle_heard) > BUNDLES_REMEMBERED:  # oldest first (insertion order)
            del d.bundle_heard[next(iter(d.bundle_heard))]
        known = d.bundle_steps.get(status.bundle_id, [])
        description = known[status.step] if status.step < len(known) else None
        if status.state == "start":
            d.bundle = BundleInfo(bundle_id=status.bundle_id, step=status.step, steps=status.steps or len(known),
                                  description=description or status.command or "step")
        elif status.ends_bundle:
            d.bundle_steps.pop(status.bundle_id, None)
            if d.bundle is not None and d.bundle.bundle_id == status.bundle_id:
                d.bundle = None
        line = bundle_line(status, description)
        out: list[Event] = [self._line(now_ms, line[0], d, line[1])] if line is not None else []
        return [*out, *self._publish(d, self._derive(d))]

    def field_readings(self) -> list[SensorReading]:
        return self.field.readings()

    def about(self, drone_id: str) -> About | None:
        return self._abouts.get(drone_id)

    def on_about(self, about: About, now_ms: int) -> list[Event]:
        """What a drone says it is: kept, logged when new or changed, in its info."""
        before = self._abouts.get(about.drone_id)
        if about.same_as(before):
            return []
        self._abouts[about.drone_id] = about
        d = self._drones.get(about.drone_id)
        if d is None:  # kept for its registration, among the newest few thousand such
            self._unregistered_abouts.pop(about.drone_id, None)
            self._unregistered_abouts[about.drone_id] = None
            if len(self._unregistered_abouts) > ABOUTS_UNREGISTERED_KEPT:
                oldest = next(iter(self._unregistered_abouts))
                del self._unregistered_abouts[oldest], self._abouts[oldest]
            return []
        return self._about_lines(d, before, now_ms) + self._publish(d, self._derive(d))

    def _about_lines(self, d: _Drone, before: About | None, now_ms: int) -> list[Event]:
        about = self._abouts[d.drone_id]
        out: list[Event] = [self._line(now_ms, "info", d, ("Declares " if before is None else "Changed what it declares: ")
                                       + describe_about(about))]
        why = relay_disagreement(self.relays, d.drone_id, list(about.roles))
        if why is not None:
            out.append(self._line(now_ms, "warn", d, f"Relay role: {why}"))
        return out

    def drop_reading(self, reading: SensorReading, now_ms: int) -> list[Event] | None:
        """None if `reading` fits what its drone declared; else it is dropped, and the
        log says so (once per DROPPED_LOG_MS per sensor type, with the count)."""
        d = self._drones.get(reading.drone_id)
        about = self._abouts.get(reading.drone_id)
        fault = reading_fault(reading, about.sensors) if about is not None else None
        if d is None or fault is None:
            if d is not None:
                d.dropping.pop(reading.type, None)
            return None
        logged, count = d.dropping.get(reading.type, (None, 0))
        if logged is not None and now_ms - logged < DROPPED_LOG_MS:
            d.dropping[reading.type] = (logged, count + 1)
            return []
        d.dropping[reading.type] = (now_ms, 0)
        more = f" ({count} more dropped since)" if count else ""
        return [self._line(now_ms, "warn", d, f"Dropped a {reading.type} reading outside its declaration: {fault}{more}")]

    def on_sensor(self, reading: SensorReading, now_ms: int) -> list[Event]:
        d = self._drones.get(reading.drone_id)
        if d is None:
            return []
        first = reading.type not in d.sensors
        d.sensors[reading.type] = _Sensor(reading, now_ms)
        if not first:
            return []
        return [self._line(now_ms, "info", d, f"Detected {reading.type} sensor"), *self._publish(d, self._derive(d))]

    def on_link(self, quality: LinkQuality, now_ms: int) -> list[Event]:
        """The drone's measured link to the ground (its `peer: ground` reports)."""
        d = self._drones.get(quality.drone_id)
        if d is None or quality.peer != GROUND_PEER:
            return []
        assert d.info is not None
        before = d.info.warns
        d.link = quality
        info = self._derive(d)
        out: list[Event] = []
        if LINK_DEGRADED in info.warns and LINK_DEGRADED not in before:
            out.append(self._line(now_ms, "warn", d, f"{LINK_DEGRADED}: quality {quality.quality:.2f}, loss {quality.loss:.0%}"
                                  + (f", rtt {quality.rtt_ms:.0f} ms" if quality.rtt_ms is not None else "")))
        return out + self._publish(d, info)

    def on_route(self, drone_id: str, routed: bool, now_ms: int) -> list[Event]:
        """Whether a query from here finds the drone's command queryable (told by the
        bus, heard or not): a drone whose commands cannot reach it is not `ready`, and
        the line says why (issue 76)."""
        self._routed[drone_id] = routed
        d = self._drones.get(drone_id)
        if d is None:
            return []
        return self._route_changed(d, now_ms)

    def _route_changed(self, d: _Drone, now_ms: int) -> list[Event]:
        out: list[Event] = []
        if self._routed.get(d.drone_id, False):
            if d.unrouted_since_ms is not None and d.unreachable_told:
                out.append(self._line(now_ms, "info", d, f"{COMMANDS_REACH} after {(now_ms - d.unrouted_since_ms) / 1000:.1f} s"))
            d.unrouted_since_ms, d.unreachable_told = None, False
        elif d.unrouted_since_ms is None:
            d.unrouted_since_ms = now_ms
        return out + self._publish(d, self._derive(d))

    def unrouted_for_ms(self, drone_id: str, now_ms: int) -> int | None:
        """How long the drone has been heard with no route to its commands; None: routed."""
        d = self._drones.get(drone_id)
        if d is None or d.unrouted_since_ms is None:
            return None
        return now_ms - d.unrouted_since_ms

    def on_liveliness(self, drone_id: str, alive: bool, now_ms: int) -> list[Event]:
        d = self._drones.get(drone_id)
        if d is None:
            return []
        d.alive = alive
        if not alive:
            d.token_lost_ms = now_ms
        if alive or d.unknown:
            return []
        return self._lose(d, now_ms, f"{LINK_LOST}: stopped receiving messages from drone (liveliness token lost)")

    def tick(self, now_ms: int) -> list[Event]:
        """Time passing: drone and sensor timeouts (the thesis's scheduled monitors)."""
        out: list[Event] = []
        if self._turned_away and now_ms - self._turned_away_told_ms >= TURNED_AWAY_EVERY_MS:
            out.append(LogLine(timestamp=now_ms, level="warn", drone_id=None, message=(
                f"Registry full (ground.max_drones {self.config.max_drones}): dropped the telemetry of "
                f"{len(self._turned_away)} drone id(s) not registered, e.g. {min(self._turned_away)!r}")))
            self._turned_away.clear()
            self._turned_away_told_ms = now_ms
        if self._unannounced and now_ms - self._unannounced_told_ms >= TURNED_AWAY_EVERY_MS:
            out.append(LogLine(timestamp=now_ms, level="warn", drone_id=None, message=(
                f"Dropped the telemetry of {len(self._unannounced)} new drone id(s) that had not said what they are "
                f"(no About heard), past ground.unannounced_per_s {self.config.unannounced_per_s:g}, "
                f"e.g. {min(self._unannounced)!r}; a drone whose agent answers `about` registers")))
            self._unannounced.clear()
            self._unannounced_told_ms = now_ms
        for d in self._drones.values():
            if not d.unknown and now_ms - d.last_telem_ms > self.config.drone_timeout_ms:
                out += self._lose(d, now_ms, f"{LINK_LOST}: stopped receiving messages from drone")
            if (not d.unknown and not d.unreachable_told and d.unrouted_since_ms is not None
                    and now_ms - d.unrouted_since_ms >= UNREACHABLE_TOLD_AFTER_MS):
                d.unreachable_told = True
                out.append(self._line(now_ms, "warn", d, f"{COMMANDS_UNREACHABLE}: heard, but no route here to its command "
                                                         f"queryable for {(now_ms - d.unrouted_since_ms) / 1000:.1f} s"))
            for kind, sensor in list(d.sensors.items()):
                limit = self.config.sensor_timeout_ms.get(kind, 0)
                if limit and now_ms - sensor.received_ms > limit:
                    del d.sensors[kind]
                    out.append(self._line(now_ms, "warn", d, f"Lost {kind} sensor: no reading for {limit} ms"))
                    out += self._publish(d, self._derive(d))
        return out

    def assign(self, drone_id: str, mission_id: str, now_ms: int) -> list[Event]:
        d = self._drones[drone_id]
        d.mission = mission_id
        return [self._line(now_ms, "info", d, f"Assigned to mission {mission_id}"), *self._publish(d, self._derive(d))]

    def release(self, drone_id: str, now_ms: int) -> list[Event]:
        d = self._drones[drone_id]
        if d.mission is None:
            return []
        mission, d.mission = d.mission, None
        return [self._line(now_ms, "info", d, f"Released from mission {mission}"), *self._publish(d, self._derive(d))]

    # ---- derivation ----------------------------------------------------------------

    def _lose(self, d: _Drone, now_ms: int, message: str) -> list[Event]:
        d.unknown = True
        d.current = None
        d.described.clear()
        return [self._line(now_ms, "warn", d, message), *self._publish(d, self._derive(d))]

    def _derive(self, d: _Drone) -> DroneInfo:
        t = d.telem
        errors: list[str] = []
        warns: list[str] = []
        if t.battery is not None:
            if t.battery.remaining_percent <= self.config.battery.critical:
                errors.append(CRITICAL_BATTERY)
            elif t.battery.remaining_percent <= self.config.battery.low:
                warns.append(LOW_BATTERY)
        if t.health_failures:
            # Not flying (on the ground, or its landed state not yet known after a start),
            # a failing check is an error at once: no autopilot arms with it, nothing is
            # lost by waiting. In flight a flag that drops for a moment is a warning; one
            # that stays down health_error_after_s is an error.
            since = d.health_failing_since_ms if d.health_failing_since_ms is not None else d.last_telem_ms
            flying = t.armed and t.landed_state in ("in_air", "taking_off", "landing")
            if not flying or d.last_telem_ms - since >= self.config.health_error_after_s * 1000:
                errors.append(f"{HEALTH_PREFIX}: {', '.join(t.health_failures)}")
            else:
                warns.append(f"{HEALTH_FAILING}: {', '.join(t.health_failures)}")
        if d.fc_disconnected:
            warns.append(FC_DISCONNECTED)
        if d.link is not None and not d.unknown and d.link.quality < self.config.link_degraded_below:
            warns.append(LINK_DEGRADED)
        state: DroneState
        if d.unknown:
            state = "unknown"
        elif errors:
            state = "error"
        elif t.flight_mode in MANUAL_MODES:
            state = "manual"
        elif d.unrouted_since_ms is not None:
            state = "unreachable"
        elif d.current is not None:
            state = "active"
        elif t.armed and t.landed_state != "on_ground":
            state = "hold"
        else:
            state = "ready"
        about = self._abouts.get(d.drone_id)
        return DroneInfo(
            drone_id=d.drone_id, state=state, current_command=d.current, sensors=sorted(d.sensors),
            mission=d.mission, errors=errors, warns=warns, link=d.link, bundle=d.bundle,
            kind=about.kind if about else None, roles=list(about.roles) if about else None,
            sensors_declared=list(about.sensors) if about else None, autopilot=about.autopilot if about else None,
        )

    def _publish(self, d: _Drone, info: DroneInfo) -> list[Event]:
        if info == d.info:
            return []
        d.info = info
        return [InfoChanged(info=info)]

    @staticmethod
    def _line(now_ms: int, level: Level, d: _Drone, message: str) -> LogLine:
        return LogLine(timestamp=now_ms, level=level, drone_id=d.drone_id, message=message)
