"""Recordings of the mesh in MCAP (SPEC §12): what `fleet record` writes, what the
ground writes per mission, and what `fleet replay` and `fleet plot` read.

One channel per key (its topic is the key as on the wire), message encoding `json`
(the payload exactly as it crossed the mesh), and one JSON schema per message kind,
generated from the msgspec Structs of `schemas/` and named `fleet.<Kind>`. Liveliness
tokens (`drone/<id>/alive`) are recorded as `fleet.Liveliness` messages on the token's
key. Log time is the time the recorder received the message (ns since the epoch).

The writer closes a chunk at least once a second of log time (`FLUSH_S`), and the
recorder's timer does the same when traffic stops: a recorder that is killed loses at
most the last second, and what it wrote is a run of whole chunks that `read()` (and
`mcap recover`) can read back without the summary at the end.
"""

from __future__ import annotations

import asyncio
import functools
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import msgspec

from dronefleet.bus.clock import Clock, SystemClock
from dronefleet.bus.keyexpr import intersects
from dronefleet.bus.port import Bus, Declaration, Sample
from dronefleet.schemas.about import About
from dronefleet.schemas.bundles import BundleStatus, TaskBundle
from dronefleet.schemas.commands import Command
from dronefleet.schemas.errors import FleetError
from dronefleet.schemas.grounds import RESERVED, ActiveGround, GroundLogLine, GroundMissionChange
from dronefleet.schemas.status import CommandStatus, SystemStatus
from dronefleet.schemas.telemetry import LinkQuality, SensorReading, Telemetry

FLUSH_S = 1.0
SCHEMA_PREFIX = "fleet."


class Liveliness(msgspec.Struct, frozen=True):
    """A liveliness token appearing (`alive: true`) or vanishing on its key."""

    alive: bool


# Message kinds of the wire contract (SPEC §2), by the last chunk of their key.
MESH_KINDS: dict[str, Any] = {
    "Telemetry": Telemetry,
    "Status": (CommandStatus, SystemStatus, BundleStatus),  # untagged: told apart by their fields
    "LinkQuality": LinkQuality,
    "SensorReading": SensorReading,
    "Command": Command,
    "TaskBundle": TaskBundle,
    "Liveliness": Liveliness,
    "About": About,
    "ActiveGround": ActiveGround,
    "GroundLogLine": GroundLogLine,
    "GroundMissionChange": GroundMissionChange,
}
_BY_LAST_CHUNK = {"telem": "Telemetry", "status": "Status", "link": "LinkQuality", "cmd": "Command",
                  "bundle": "TaskBundle", "alive": "Liveliness", "about": "About"}
# Sent as queries (commands, bundles) or the ground's own: kept in a recording, never replayed.
# A ground's epoch (SPEC §14) is kept too: replayed into a live mesh, it would fence its grounds.
NOT_REPLAYED = frozenset({"Command", "TaskBundle", "ActiveGround", "GroundLogLine", "GroundMissionChange"})


def kind_of(key: str) -> str | None:
    """The message kind of a key, whatever namespace it is under: `…/drone/<id>/telem`
    → Telemetry, `…/drone/<id>/sensor/<type>` and `…/sensor/<id>/<type>` →
    SensorReading, `…/drone/<id>/about` → About, `…/ground/alive`, `…/ground/<ground_id>` and `…/sensor/<id>/alive` → Liveliness,
    `…/ground/<ground_id>/active` → ActiveGround; None for keys outside the contract."""
    parts = key.split("/")
    if len(parts) >= 3 and parts[-3] == "drone" and parts[-1] in _BY_LAST_CHUNK:
        return _BY_LAST_CHUNK[parts[-1]]
    if len(parts) >= 4 and parts[-4] == "drone" and parts[-2] == "sensor":
        return "SensorReading"
    if len(parts) >= 3 and parts[-3] == "sensor":  # a field sensor: its readings and its token
        return "Liveliness" if parts[-1] == "alive" else "SensorReading"
    if parts[-2:] == ["ground", "alive"]:
        return "Liveliness"
    if len(parts) >= 3 and parts[-3] == "ground" and parts[-1] == "active":  # SPEC §14: the active ground's epoch
        return "ActiveGround"
    if len(parts) >= 3 and parts[-3] == "ground" and parts[-1] == "log":  # … its event log, line by line
        return "GroundLogLine"
    if len(parts) >= 3 and parts[-3] == "ground" and parts[-1] == "missions":  # … and its missions' changes
        return "GroundMissionChange"
    if len(parts) >= 2 and parts[-2] == "ground" and parts[-1] not in RESERVED:  # a ground's own token
        return "Liveliness"
    return None


def json_schema(kind: str, kinds: dict[str, Any] = MESH_KINDS) -> bytes:
    of = kinds[kind]
    if isinstance(of, tuple):  # one of several Structs (msgspec's schema() wants them tagged)
        refs, defs = msgspec.json.schema_components(of, ref_template="#/$defs/{name}")
        schema: dict[str, Any] = {"anyOf": list(refs), "$defs": defs}
    else:
        schema = msgspec.json.schema(of)
    schema["title"] = SCHEMA_PREFIX + kind
    return json.dumps(schema, sort_keys=True).encode()


class Recorder:
    """An MCAP file being written: channels and schemas are registered on first use.

    `kinds` adds message kinds beyond the mesh's (the ground's mission records, say).
    A payload of a known kind that is not JSON is written on a channel without schema
    rather than lost."""

    def __init__(self, out: Path | IO[bytes], *, kinds: dict[str, Any] | None = None,
                 metadata: dict[str, str] | None = None, schemas: dict[str, bytes] | None = None) -> None:
        from mcap.writer import CompressionType, Writer  # the `record` extra

        self.path = out if isinstance(out, Path) else None
        self._file: IO[bytes] = open(out, "wb") if isinstance(out, Path) else out  # noqa: SIM115 (closed in close())
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="fleet")
        if metadata:
            self._writer.add_metadata("fleet", metadata)
        self.kinds = {**MESH_KINDS, **(kinds or {})}
        self._given_schemas = schemas or {}  # kind → JSON schema, kept as another recording had it
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str | None], int] = {}
        self._flushed_ns: int | None = None
        self.messages = 0
        self.closed = False

    def _channel(self, topic: str, kind: str | None) -> int:
        channel = self._channels.get((topic, kind))
        if channel is None:
            schema = 0
            if kind is not None:
                schema = self._schemas.get(kind) or self._writer.register_schema(
                    SCHEMA_PREFIX + kind, "jsonschema", self._given_schemas.get(kind) or json_schema(kind, self.kinds))
                self._schemas[kind] = schema
            channel = self._writer.register_channel(topic, "json", schema)
            self._channels[(topic, kind)] = channel
        return channel

    def write(self, topic: str, payload: bytes, log_ns: int, kind: str | None = None) -> None:
        """One message; `kind` defaults to the kind of the topic as a mesh key."""
        if self.closed:
            return
        kind = kind if kind is not None else kind_of(topic)
        if kind is not None:
            try:
                msgspec.json.decode(payload)
            except msgspec.DecodeError:
                kind = None
        self._writer.add_message(self._channel(topic, kind), log_time=log_ns, data=payload, publish_time=log_ns,
                                 sequence=self.messages)
        self.messages += 1
        self.tick(log_ns)

    def write_struct(self, topic: str, value: Any, log_ns: int, kind: str) -> None:
        self.write(topic, msgspec.json.encode(value), log_ns, kind)

    def tick(self, now_ns: int) -> None:
        """Close the chunk in progress once a second (of log time)."""
        if self._flushed_ns is None:
            self._flushed_ns = now_ns
        elif now_ns - self._flushed_ns >= FLUSH_S * 1e9:
            self._writer.flush()
            self._flushed_ns = now_ns

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._writer.finish()
        self._file.close()


def now_ns_of(clock: Clock) -> Callable[[], int]:
    """Log time from a clock: wall time in ns, or a virtual clock's (reproducible)."""
    if isinstance(clock, SystemClock):
        return time.time_ns
    return lambda: clock.time_ms() * 1_000_000


class BusRecording:
    """Everything under a key expression on a bus, samples and liveliness, into one
    subscription's Recorders: `fleet record`'s one file, or the ground's open mission
    recordings, added and removed while it runs (one that joins late is told the
    tokens alive at that moment)."""

    def __init__(self, bus: Bus, recorders: list[Recorder], keyexprs: str | Sequence[str] = "**",
                 now_ns: Callable[[], int] = time.time_ns) -> None:
        self.recorders = list(recorders)
        self.now_ns = now_ns
        self._alive: set[str] = set()
        self._declarations: list[Declaration] = []
        keyexprs = [keyexprs] if isinstance(keyexprs, str) else list(keyexprs)
        for i, keyexpr in enumerate(keyexprs):
            # A key under several of them is recorded by the first one only, once.
            earlier = tuple(keyexprs[:i])
            self._declarations += [
                bus.subscribe(keyexpr, functools.partial(self._on_sample, earlier), maxsize=1_000_000),
                bus.watch_liveliness(keyexpr, functools.partial(self._on_liveliness, earlier)),
            ]

    def add(self, recorder: Recorder) -> None:
        now = self.now_ns()
        for key in sorted(self._alive):
            recorder.write_struct(key, Liveliness(True), now, "Liveliness")
        self.recorders.append(recorder)

    def remove(self, recorder: Recorder) -> None:
        self.recorders.remove(recorder)

    def _on_sample(self, earlier: tuple[str, ...], sample: Sample) -> None:
        if sample.kind == "put" and not any(intersects(k, sample.key) for k in earlier):
            now = self.now_ns()
            for recorder in self.recorders:
                recorder.write(sample.key, sample.payload, now)

    def _on_liveliness(self, earlier: tuple[str, ...], key: str, alive: bool) -> None:
        if any(intersects(k, key) for k in earlier):
            return
        (self._alive.add if alive else self._alive.discard)(key)
        payload, now = msgspec.json.encode(Liveliness(alive)), self.now_ns()
        for recorder in self.recorders:
            recorder.write(key, payload, now, "Liveliness")

    def tick(self) -> None:
        now = self.now_ns()
        for recorder in self.recorders:
            recorder.tick(now)

    def close(self) -> None:
        """Stop listening and close the Recorders still here."""
        for declaration in self._declarations:
            declaration.close()
        self._declarations.clear()
        for recorder in self.recorders:
            recorder.close()


# ---- reading -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Message:
    topic: str
    kind: str | None  # the schema's kind (`Telemetry`), None on a channel without schema
    log_ns: int
    data: bytes


@dataclass
class Contents:
    """What a recording holds, read from its first byte (so also a truncated one)."""

    messages: list[Message]
    schemas: dict[str, bytes]  # kind → JSON schema
    metadata: dict[str, str]
    complete: bool  # False: the writer was killed; `messages` is what it had written


def read(path: Path) -> Contents:
    """Every message in file order (the order they were received), tolerating a file
    cut short by a killed recorder."""
    from mcap.records import Channel, DataEnd, Metadata, Schema
    from mcap.records import Message as McapMessage
    from mcap.stream_reader import StreamReader

    schemas: dict[int, tuple[str, bytes]] = {}
    channels: dict[int, tuple[str, str | None]] = {}
    metadata: dict[str, str] = {}
    messages: list[Message] = []
    complete = False
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
                if isinstance(record, Schema):
                    name = record.name.removeprefix(SCHEMA_PREFIX)
                    schemas[record.id] = (name, record.data)
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, schemas[record.schema_id][0] if record.schema_id else None)
                elif isinstance(record, McapMessage):
                    topic, kind = channels[record.channel_id]
                    messages.append(Message(topic, kind, record.log_time, record.data))
                elif isinstance(record, Metadata) and record.name == "fleet":
                    metadata.update(record.metadata)
                elif isinstance(record, DataEnd):
                    complete = True
                    break
        except Exception as exc:  # noqa: BLE001 — any cut (EOF, a half chunk) ends the readable part
            if not messages and not schemas:
                raise RecordingError(f"{path}: not an MCAP recording ({type(exc).__name__}: {exc})") from None
    return Contents(messages, {name: data for name, data in schemas.values()}, metadata, complete)


class RecordingError(FleetError):
    """A file that is not a recording Fleet can read (the CLI: one line, exit 2)."""

    exit_code = 2


def recover(src: Path, dst: Path) -> Contents:
    """Write what a cut recording holds as a complete MCAP file."""
    contents = read(src)
    # Kinds beyond the mesh's (a ground's mission records) keep the schema the cut file had.
    recorder = Recorder(dst, metadata=contents.metadata or None, schemas=contents.schemas)
    for message in contents.messages:
        recorder.write(message.topic, message.data, message.log_ns, message.kind)
    recorder.close()
    return contents


# ---- replay --------------------------------------------------------------------------


class Replay:
    """Publish a recording again on a bus, keeping its timing (divided by `speed`):
    samples are put on their keys, liveliness tokens declared and undeclared. Commands
    and bundles (queries the ground sent), the ground's own liveliness and messages
    outside the wire contract are not replayed: a replay never flies a drone."""

    def __init__(self, bus: Bus, contents: Contents, clock: Clock, speed: float = 1.0) -> None:
        if speed <= 0:
            raise ValueError("speed must be > 0")
        self.bus = bus
        self.contents = contents
        self.clock = clock
        self.speed = speed
        self.tokens: dict[str, Declaration] = {}
        self.published = 0

    @staticmethod
    def replayed(message: Message) -> bool:
        if message.kind is None or message.kind in NOT_REPLAYED or message.kind not in MESH_KINDS:
            return False
        return not (message.kind == "Liveliness" and message.topic.split("/")[-2] == "ground")  # grounds' tokens

    async def run(self, progress: Callable[[int, int], None] | None = None) -> None:
        messages = [m for m in self.contents.messages if self.replayed(m)]
        if not messages:
            return
        t0, start = messages[0].log_ns, self.clock.monotonic()
        for n, message in enumerate(messages):
            due = start + (message.log_ns - t0) / 1e9 / self.speed
            wait = due - self.clock.monotonic()
            if wait > 0:
                await self.clock.sleep(wait)
            self._send(message)
            if progress is not None:
                progress(n + 1, len(messages))

    def _send(self, message: Message) -> None:
        if message.kind == "Liveliness":
            alive = msgspec.json.decode(message.data, type=Liveliness).alive
            token = self.tokens.pop(message.topic, None)
            if token is not None:
                token.close()
            if alive:
                self.tokens[message.topic] = self.bus.announce(message.topic)
        else:
            reliable = message.kind not in ("Telemetry", "LinkQuality")
            self.bus.publish(message.topic, message.data, reliable=reliable)
        self.published += 1

    def close(self) -> None:
        for token in self.tokens.values():
            token.close()
        self.tokens.clear()


async def record_until_stopped(bus: Bus, recorder: Recorder, keyexprs: Sequence[str], stop: asyncio.Event,
                               now_ns: Callable[[], int] = time.time_ns) -> BusRecording:
    """`fleet record`'s loop: record until `stop`, closing a chunk every FLUSH_S."""
    recording = BusRecording(bus, [recorder], keyexprs, now_ns)
    try:
        while not stop.is_set():
            try:
                await asyncio.wait_for(stop.wait(), FLUSH_S)
            except TimeoutError:
                recording.tick()
    finally:
        recording.close()
    return recording
