"""A mission in a process of its own: the worker's side (SPEC §9, ADR 0009).

The ground forks one worker per mission (`mission.isolation`). The worker limits
itself before it reads the script — `RLIMIT_AS` at its own size plus
`mission.max_memory_mb`, `RLIMIT_CPU` at `mission.max_cpu_s` — then runs the very
same `Mission` as the ground would, with `WorkerPort` for the ground's `FleetPort`:

- what the ground knows (`registry`) is a copy, `Mirror`, kept from the events the
  ground forwards in order (a snapshot first, then every telemetry, status, sensor
  reading and drone change), so reading it costs nothing and never waits;
- what changes the fleet (claiming a drone, sending a command or a bundle) is a call
  the ground answers, and the ground makes it as this mission and no other.

One socket carries everything, in both directions, as length-prefixed msgpack
frames. Because the ground writes events and answers on the same ordered stream, a
refusal to claim a drone arrives after the event that showed another mission took it.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import os
import resource
import signal
import socket
import time
import uuid
from collections.abc import Callable
from typing import Any, Literal

import msgspec

from dronefleet.bus.port import QueryTimeout, Unreachable
from dronefleet.mission.hosting.journal import Driver, Entry, mission_clock
from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.lifecycle.record import Activity, MissionLogLine, MissionRecord
from dronefleet.mission.script.plugins import PluginLibrary
from dronefleet.mission.script.sandbox import compile_mission
from dronefleet.mission.script.script import ScriptMission
from dronefleet.schemas.bundles import BundleRecord, BundleReply
from dronefleet.schemas.codec import decode_sensor, decode_status, decode_telemetry
from dronefleet.schemas.commands import CommandReply
from dronefleet.schemas.config_loading import MissionSettings
from dronefleet.schemas.errors import CommandRejected, FleetError, InvalidMessage
from dronefleet.schemas.fleet import DroneInfo, WatchEvent
from dronefleet.schemas.telemetry import SensorReading, Telemetry

log = logging.getLogger(__name__)

MAX_FRAME = 16 * 2**20  # bytes; a record, a log line or a reply is far smaller
CLOSE_WAIT_S = 5.0  # after Done: how long the worker waits for the ground to close
MEMORY_EXIT = 3  # the worker's exit status when it ran out of memory outside the script
EVENT_KINDS = ("telemetry", "status", "drone", "sensor", "field_sensor", "field_sensor_lost")
Op = Literal["assign", "command", "push", "bundle_record"]


# ---- the frames ----------------------------------------------------------------------


class Event(msgspec.Struct, tag=True, frozen=True):
    """Ground → worker: one event the ground's listeners heard (data: its JSON)."""

    kind: str
    data: bytes


class Failure(msgspec.Struct, frozen=True, kw_only=True):
    kind: Literal["rejected", "invalid", "unreachable", "timeout", "error"]
    reason: str
    status: int = 0
    code: str | None = None
    other: str | None = None
    field: str | None = None


class Reply(msgspec.Struct, tag=True, frozen=True, kw_only=True):
    """Ground → worker: the answer to a Call (result: the reply's JSON)."""

    call: int
    result: bytes = b""
    failure: Failure | None = None


class End(msgspec.Struct, tag=True, frozen=True):
    """Ground → worker: end the mission (a DELETE, the ground stopping)."""

    cause: str
    message: str | None = None


class Call(msgspec.Struct, tag=True, frozen=True, kw_only=True):
    """Worker → ground: something only the ground may do; `arg` is the command or
    bundle JSON, or the bundle id."""

    call: int
    op: Op
    drone_id: str
    arg: bytes = b""


class Release(msgspec.Struct, tag=True, frozen=True):
    drone_id: str


class Changed(msgspec.Struct, tag=True, frozen=True):
    record: MissionRecord


class Logged(msgspec.Struct, tag=True, frozen=True):
    line: MissionLogLine


class Active(msgspec.Struct, tag=True, frozen=True):
    activity: Activity


class GroundLog(msgspec.Struct, tag=True, frozen=True):
    level: Literal["info", "warn", "error"]
    message: str


class Ack(msgspec.Struct, tag=True, frozen=True):
    """Worker → ground: an End was heard (so the worker is not stuck in one long call)."""


class Done(msgspec.Struct, tag=True, frozen=True):
    record: MissionRecord


class Journalled(msgspec.Struct, tag=True, frozen=True):
    """Worker → ground: a frame the mission took, for its journal (mission.journal)."""

    entry: Entry


class Resumed(msgspec.Struct, tag=True, frozen=True):
    """Worker → ground: the journal is replayed; the mission holds these drones and goes
    on live (its calls still unanswered follow). The replay wrote `log` and `activities`
    again, as the first run had: the ground keeps the lines its copy of the log lacks
    (those written after the last line that reached it) and the subroutines' lanes."""

    held: list[str]
    log: list[MissionLogLine] = []
    activities: list[Activity] = []


ToWorker = Event | Reply | End
ToGround = Call | Release | Changed | Logged | Active | GroundLog | Ack | Done | Journalled | Resumed


class Start(msgspec.Struct, frozen=True, kw_only=True):
    """What the worker is started with."""

    record: MissionRecord
    source: str
    settings: MissionSettings
    plugins: list[tuple[str, str]]  # (path, source) of every plugin the ground loaded
    enable: dict[str, dict[str, Any]] | None
    snapshot: list[Event]  # the registry as the ground knew it at the start
    relays: list[str] | None  # the drones that may relay (Registry.relays)
    uid: str  # this run of the mission, whichever ground hosts it: its command and bundle ids derive from it
    started_ms: int  # wall time at mission time 0
    seed: int  # the script's `random`
    journal: list[Entry] | None = None  # a takeover: the frames to take again before going on live


_encoder = msgspec.msgpack.Encoder()


def frame(message: Any) -> bytes:
    body = _encoder.encode(message)
    return len(body).to_bytes(4, "big") + body


async def read_frame(reader: asyncio.StreamReader) -> bytes | None:
    """One frame's body, or None at the end of the stream. Raises ValueError for a
    frame over MAX_FRAME."""
    try:
        size = int.from_bytes(await reader.readexactly(4), "big")
        if size > MAX_FRAME:
            raise ValueError(f"a frame of {size} bytes (the limit is {MAX_FRAME})")
        return await reader.readexactly(size)
    except (asyncio.IncompleteReadError, ConnectionError):  # the other side is gone (killed, say)
        return None


def failure_of(exc: BaseException) -> Failure:
    if isinstance(exc, CommandRejected):
        return Failure(kind="rejected", reason=exc.reason, status=exc.status, code=exc.code, other=exc.other)
    if isinstance(exc, InvalidMessage):
        return Failure(kind="invalid", reason=exc.reason, field=exc.field)
    if isinstance(exc, QueryTimeout):
        return Failure(kind="timeout", reason=str(exc))
    if isinstance(exc, Unreachable):
        return Failure(kind="unreachable", reason=str(exc))
    return Failure(kind="error", reason=f"{type(exc).__name__}: {exc}")


def exception_of(failure: Failure) -> Exception:
    if failure.kind == "rejected":
        return CommandRejected(failure.status, failure.reason, failure.code, failure.other)
    if failure.kind == "invalid":
        return InvalidMessage(failure.reason, failure.field)
    if failure.kind == "timeout":
        return QueryTimeout(failure.reason)
    if failure.kind == "unreachable":
        return Unreachable(failure.reason)
    return FleetError(failure.reason)


# ---- the worker's view of the fleet ----------------------------------------------------


_decode_info = msgspec.json.Decoder(DroneInfo).decode


class Mirror:
    """The ground's registry as the events so far tell it (FleetView)."""

    def __init__(self, relays: list[str] | None = None) -> None:
        self.relays = None if relays is None else frozenset(relays)
        self._infos: dict[str, DroneInfo] = {}
        self._telemetry: dict[str, Telemetry] = {}
        self._readings: dict[str, dict[str, SensorReading]] = {}
        self._field: dict[tuple[str, str], SensorReading] = {}  # (sensor id, type) → latest

    def apply(self, kind: str, data: bytes) -> Any:
        """Take one event in; returns its decoded data."""
        if kind == "telemetry":
            telem = decode_telemetry(data)
            self._telemetry[telem.drone_id] = telem
            return telem
        if kind == "drone":
            info = _decode_info(data)
            self._infos[info.drone_id] = info
            return info
        if kind == "sensor":
            reading = decode_sensor(data)
            self._readings.setdefault(reading.drone_id, {})[reading.type] = reading
            return reading
        if kind == "field_sensor":
            reading = decode_sensor(data)
            self._field[(reading.sensor_id or "", reading.type)] = reading
            return reading
        if kind == "field_sensor_lost":
            lost = msgspec.json.decode(data)
            self._field.pop((lost["sensor_id"], lost["type"]), None)
            return lost
        return decode_status(data)

    def __contains__(self, drone_id: str) -> bool:
        return drone_id in self._infos and drone_id in self._telemetry

    def ids(self) -> list[str]:
        return sorted(d for d in self._infos if d in self._telemetry)

    def info(self, drone_id: str) -> DroneInfo:
        return self._infos[drone_id]

    def telemetry(self, drone_id: str) -> Telemetry:
        return self._telemetry[drone_id]

    def field_readings(self) -> list[SensorReading]:
        return [self._field[k] for k in sorted(self._field)]

    def sensor_readings(self, drone_id: str) -> list[SensorReading]:
        present = set(self._infos[drone_id].sensors)  # the ground drops a sensor that timed out
        readings = self._readings.get(drone_id, {})
        return [readings[t] for t in sorted(readings) if t in present]


class _Settings:
    def __init__(self, settings: MissionSettings) -> None:
        self.mission = settings


class WorkerPort:
    """The FleetPort of a mission in its own process."""

    def __init__(self, settings: MissionSettings, send: Callable[[Any], None], relays: list[str] | None = None,
                 uid: str = "", replayed: Callable[[Any], None] = lambda message: None) -> None:
        """`uid`: the mission's run, whose command ids are uuid5s of it and a count, the
        same when a journal is replayed (an agent answers a command id it has seen as
        before, and does nothing again)."""
        self.config = _Settings(settings)
        self.registry = Mirror(relays)
        self._out = send
        self._replayed = replayed
        self._listeners: list[Callable[[WatchEvent], None]] = []
        self._calls: dict[int, tuple[asyncio.Future[bytes], Call]] = {}
        self._ids = itertools.count(1)
        self._command_ids = itertools.count(1)
        self._uid = uuid.UUID(uid) if uid else uuid.uuid4()
        self._gone: str | None = None
        self.held: set[str] = set()  # the drones its claims won and it has not released
        self.replaying = False  # taking a journal again: nothing goes out
        self._retold: list[Logged | Active] = []  # what the replay wrote again

    def emit(self, message: Any) -> None:
        """A frame to the ground (none while a journal is replayed)."""
        if self.replaying:
            if isinstance(message, Logged | Active):
                self._retold.append(message)
            self._replayed(message)
        else:
            self._out(message)

    def go_live(self) -> None:
        """The journal is replayed: say which drones the mission holds and what the
        replay wrote, then make the calls the journal holds no answer to (their effects
        are idempotent: ids)."""
        self.replaying = False
        retold, self._retold = self._retold, []
        self._out(Resumed(sorted(self.held), log=[m.line for m in retold if isinstance(m, Logged)],
                          activities=[m.activity for m in retold if isinstance(m, Active)]))
        for _, call in sorted(self._calls.values(), key=lambda fc: fc[1].call):
            self._out(call)

    # ---- from the ground ----

    def on_event(self, event: Event) -> None:
        data = self.registry.apply(event.kind, event.data)
        watch = WatchEvent(event.kind, data)
        for listener in list(self._listeners):
            listener(watch)

    def on_reply(self, reply: Reply) -> None:
        fut, call = self._calls.pop(reply.call, (None, None))
        if fut is None or call is None or fut.done():
            return
        if reply.failure is not None:
            fut.set_exception(exception_of(reply.failure))
        else:
            if call.op == "assign":
                self.held.add(call.drone_id)
            fut.set_result(reply.result)

    def ground_gone(self) -> None:
        self._gone = "the ground station closed the mission's connection"
        for fut, _ in self._calls.values():
            if not fut.done():
                fut.set_exception(Unreachable(self._gone))
        self._calls.clear()

    # ---- FleetPort ----

    def listen(self, listener: Callable[[WatchEvent], None]) -> Callable[[], None]:
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener) if listener in self._listeners else None

    async def _call(self, op: Op, drone_id: str, arg: bytes = b"") -> bytes:
        if self._gone is not None:
            raise Unreachable(self._gone)
        message = Call(call=next(self._ids), op=op, drone_id=drone_id, arg=arg)
        fut: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        self._calls[message.call] = (fut, message)
        self.emit(message)
        return await fut

    async def assign(self, drone_id: str, mission_id: str) -> None:
        await self._call("assign", drone_id)

    def release(self, drone_id: str) -> None:
        self.held.discard(drone_id)
        if self._gone is None:
            self.emit(Release(drone_id))

    async def command(self, drone_id: str, body: bytes, mission_id: str | None = None) -> CommandReply:
        return msgspec.json.decode(await self._call("command", drone_id, body), type=CommandReply)

    async def push(self, drone_id: str, body: bytes, mission_id: str | None = None) -> BundleReply:
        return msgspec.json.decode(await self._call("push", drone_id, body), type=BundleReply)

    async def bundle_record(self, drone_id: str, bundle_id: str) -> BundleRecord:
        return msgspec.json.decode(await self._call("bundle_record", drone_id, bundle_id.encode()), type=BundleRecord)

    def log_ground(self, level: str, message: str) -> None:
        if self._gone is None and level in ("info", "warn", "error"):
            self.emit(GroundLog(level, message))  # type: ignore[arg-type]

    def new_command_id(self) -> str:
        return str(uuid.uuid5(self._uid, f"command {next(self._command_ids)}"))


# ---- the process ---------------------------------------------------------------------


def limit_self(max_memory_mb: int, max_cpu_s: float) -> None:
    """Address space: what the process has now plus `max_memory_mb`; CPU: `max_cpu_s`
    in all (SIGXCPU at the soft limit, SIGKILL a second later); no core files."""
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    with open("/proc/self/statm") as statm:
        size = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    limit = size + max_memory_mb * 2**20
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu = math.ceil(usage.ru_utime + usage.ru_stime + max_cpu_s)
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))


def main(sock: socket.socket, start: bytes, max_memory_mb: int, max_cpu_s: float) -> None:
    """The worker process's entry (multiprocessing target)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the ground's to handle; it ends us
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    limit_self(max_memory_mb, max_cpu_s)
    try:
        asyncio.run(_serve(sock, msgspec.msgpack.decode(start, type=Start)))
    except MemoryError:
        _exit_out_of_memory()


def _exit_out_of_memory() -> None:
    """Out of memory outside the script (an event, a frame): the ground tells the
    mission's end from this exit status."""
    os.write(2, b"fleet mission worker: out of memory (mission.max_memory_mb)\n")
    os._exit(MEMORY_EXIT)


def _out_of_memory(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    if isinstance(context.get("exception"), MemoryError):
        _exit_out_of_memory()
    loop.default_exception_handler(context)


async def _serve(sock: socket.socket, start: Start) -> None:
    asyncio.get_running_loop().set_exception_handler(_out_of_memory)
    reader, writer = await asyncio.open_unix_connection(sock=sock)
    await serve(reader, writer, start)


async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, start: Start,
                replayed: Callable[[Any], None] = lambda message: None) -> None:
    """Run the mission of `start` over one stream to its ground until it ends or the
    ground goes. `replayed` sees each frame the mission would have sent while its journal
    was taken again (none goes out): a replay makes what the original run made."""

    def send(message: Any) -> None:
        writer.write(frame(message))

    port = WorkerPort(start.settings, send, start.relays, uid=start.uid, replayed=replayed)
    for event in start.snapshot:
        port.registry.apply(event.kind, event.data)
    mission_id = start.record.mission_id
    # On a clock of its own that only the driver moves, slicing its work by count: what
    # it does follows from the frames it takes, so its journal can run it again.
    clock = mission_clock(start.started_ms)
    mission = ScriptMission(
        start.record, compile_mission(start.source, filename=f"<mission {mission_id}>"), port, clock,
        deterministic=True, seed=start.seed,
        on_change=lambda m: port.emit(Changed(m.record)),
        on_log=lambda m, line: port.emit(Logged(line)),
        plugins=PluginLibrary.from_sources(start.plugins), enable=start.enable,
    )
    mission.uid = start.uid
    mission.on_activity = lambda m, activity: port.emit(Active(activity))

    def deliver(message: ToWorker) -> None:
        if isinstance(message, Event):
            port.on_event(message)
        elif isinstance(message, Reply):
            port.on_reply(message)
        elif port.replaying:  # live, `_listen` applied it as it came
            mission.end(message.cause, message.message)

    driver = Driver(clock, deliver, _decode_to_worker, record=lambda entry: send(Journalled(entry)))
    frames: asyncio.Queue[tuple[bytes, ToWorker] | None] = asyncio.Queue()
    listen = asyncio.ensure_future(_listen(reader, frames, mission, writer))
    run = asyncio.ensure_future(mission.run())
    if start.journal is not None:
        port.replaying = True
        began = time.perf_counter()
        await driver.replay(start.journal)
        took_ms = (time.perf_counter() - began) * 1000
        port.go_live()
        send(Changed(mission.record))
        mission.log("info", f"Journal taken again: {len(start.journal)} entries in {took_ms:.0f} ms; live from here")
    drive = asyncio.ensure_future(driver.live(frames))
    await asyncio.wait([run, drive], return_when=asyncio.FIRST_COMPLETED)
    if listen.done() and isinstance(listen.exception(), MemoryError):
        raise MemoryError
    if run.done():
        send(Done(run.result()))
        # Closing now would make the ground's next event fail (EPIPE), and its reader
        # drop the Done still buffered: wait for the ground to close first.
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.shield(listen), CLOSE_WAIT_S)
    else:  # the ground is gone: nobody to tell, nothing to send commands through
        port.ground_gone()
        run.cancel()
    listen.cancel()
    drive.cancel()
    await asyncio.gather(run, listen, drive, return_exceptions=True)
    try:
        await writer.drain()
        writer.close()
    except OSError:
        pass


_decode_to_worker = msgspec.msgpack.Decoder(ToWorker).decode


async def _listen(reader: asyncio.StreamReader, frames: asyncio.Queue[tuple[bytes, ToWorker] | None],
                  mission: Mission, writer: asyncio.StreamWriter) -> None:
    """The ground's frames, decoded, in order, for the driver (None at the end). An End
    is applied here, at once: a script computing without a verb stops at its next slice
    (the driver still journals it, for a replay to end there too)."""
    while (body := await read_frame(reader)) is not None:
        message = _decode_to_worker(body)
        if isinstance(message, End):
            mission.end(message.cause, message.message)
            writer.write(frame(Ack()))
        frames.put_nowait((body, message))
    frames.put_nowait(None)
