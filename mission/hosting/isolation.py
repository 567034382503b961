"""A mission in a process of its own: the ground's side (SPEC §9, ADR 0009).

`IsolatedMission` stands where a `Mission` would in the manager (`record`, `end`,
`run`). It forks a worker (`mission.worker`) from a fork server that has the mission
runtime imported already, so a mission starts in milliseconds, not the interpreter's
quarter second. It forwards the station's events to the worker and does for it only
what a mission may do, always as this mission: claim and release its drones, send
commands and bundles, log.

A script that goes beyond `mission.max_memory_mb` or `mission.max_cpu_s` kills its
own process (the kernel's limits) or fails with MemoryError; either way the mission
fails with cause `security` and this side leaves its drones as a mission's end does
(hold or return, then release). So does a worker that does not answer an end within
`STOP_GRACE_S` (one long call in C code): it is killed. The ground's loop, its
memory, telemetry and the other missions are never at stake.

The worker journals every frame it takes (mission.hosting.journal); this side keeps
the journal in batches (`on_journal`), and always before what the mission does goes
out (write-ahead), and a ground taking over from a lost one starts the worker with it
(`resume`) so the mission goes on where it was (ADR 0017).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import random
import signal
import socket
import uuid
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.context import ForkServerContext
from typing import Any, Literal

import msgspec

from dronefleet.bus.clock import Clock
from dronefleet.mission.hosting import worker
from dronefleet.mission.hosting.journal import Entry
from dronefleet.mission.lifecycle.delivery import leave
from dronefleet.mission.lifecycle.fleet_port import GroundPort
from dronefleet.mission.lifecycle.mission import STOP_GRACE_S
from dronefleet.mission.lifecycle.record import CAUSES, Activity, MissionLogLine, MissionRecord, mark_ended
from dronefleet.mission.script.plugins import PluginLibrary
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.fleet import CRITICAL_BATTERY, WatchEvent

log = logging.getLogger(__name__)

MAX_BACKLOG = 64 * 2**20  # bytes of events a worker has not read: it is stuck in one call
EXIT_WAIT_S = 5.0  # how long a worker that said Done (or closed) may take to exit
JOURNAL_FLUSH_S = 0.1  # the journal's entries are kept (and go to the standby grounds) in batches this often
_context: ForkServerContext | None = None


@dataclass(frozen=True)
class Resume:
    """A mission another ground ran, to take over (SPEC §14): its first Start, the
    journal as this ground's copy holds it, and the copy of its log (the lines the
    replay writes again and the copy lacks are added to it)."""

    start: worker.Start
    journal: list[Entry]
    log: list[MissionLogLine]


def fork_server() -> ForkServerContext:
    """The multiprocessing context whose fork server has the runtime imported."""
    global _context
    if _context is None:
        _context = multiprocessing.get_context("forkserver")
        _context.set_forkserver_preload(["dronefleet.mission.hosting.worker"])
    return _context


class IsolatedMission:
    def __init__(
        self,
        record: MissionRecord,
        source: str,
        station: GroundPort,
        clock: Clock,
        *,
        on_change: Callable[[IsolatedMission], None] = lambda m: None,
        on_log: Callable[[IsolatedMission, MissionLogLine], None] = lambda m, line: None,
        plugins: PluginLibrary | None = None,
        enable: dict[str, dict[str, Any]] | None = None,
        on_journal: Callable[[IsolatedMission, str, bytes], None] = lambda m, kind, body: None,
        resume: Resume | None = None,
    ) -> None:
        """`on_journal(mission, kind, body)` keeps its journal: kind `start` (the
        worker's Start, msgpack) once, then `entries` (msgpack list of Entry) in order.
        `resume`: another ground's Start and journal to take over (SPEC §14)."""
        self.record = record
        self.source = source
        self.station = station
        self.settings = station.config.mission
        self.clock = clock
        self._on_change = on_change
        self._on_log = on_log
        self.on_activity: Callable[[IsolatedMission, Activity], None] = lambda m, activity: None
        self.plugins = plugins
        self.enable = enable
        self._writer: asyncio.StreamWriter | None = None
        self._process: Any = None
        self._exited: asyncio.Future[None] | None = None
        self._requested: tuple[str, str | None] | None = None
        self._acked = asyncio.Event()
        self._killed: tuple[str, str] | None = None  # why this side killed the worker (cause, message)
        self._reported: str | None = None  # the cause the worker last reported
        self._tasks: set[asyncio.Task[None]] = set()
        self._on_journal = on_journal
        self._resume = resume
        self._journal: list[Entry] = []  # entries not yet kept
        self._flushing: asyncio.TimerHandle | None = None

    @property
    def id(self) -> str:
        return self.record.mission_id

    # ---- what the manager calls ----------------------------------------------------

    def end(self, cause: str, message: str | None = None) -> bool:
        """Ask the worker to end the mission; kill it if it does not answer in time.
        The record shows the end at once (the worker's own report follows)."""
        if self.record.cause is not None or self._requested is not None:
            return False
        self._requested = (cause, message)
        mark_ended(self.record, cause, message)  # its log line is the worker's to write
        if self._process is not None:
            self._send(worker.End(cause, message))
            self._spawn(self._expect_ack())
        return True

    async def run(self) -> MissionRecord:
        """Run the mission in its process to its end; never raises (but CancelledError)."""
        parent, child = socket.socketpair()
        stop_listening: Callable[[], None] = lambda: None  # noqa: E731
        try:
            reader, self._writer = await asyncio.open_unix_connection(sock=parent)
            if self._requested is not None:  # ended before it started
                await self._conclude(*self._requested)
                return self.record
            if self._resume is None:
                start = worker.Start(
                    record=self.record, source=self.source, settings=self.settings,
                    plugins=self.plugins.sources() if self.plugins is not None else [],
                    enable=self.enable, snapshot=self._snapshot(),
                    relays=None if self.station.registry.relays is None else sorted(self.station.registry.relays),
                    uid=str(uuid.uuid4()), started_ms=self.clock.time_ms(), seed=random.getrandbits(32),
                )
                self._on_journal(self, "start", msgspec.msgpack.encode(start))
            else:  # its first Start, then its journal; the fleet as this ground sees it follows live
                start = msgspec.structs.replace(self._resume.start, journal=self._resume.journal)
                for event in self._snapshot():
                    self._send(event)
                # What the drones said of their commands while no ground was active (a
                # leg that ended then): the mission takes what its journal lacks.
                for drone_id in self.station.registry.ids():
                    for status in self.station.registry.command_statuses(drone_id):
                        self._send(worker.Event("status", msgspec.json.encode(status)))
            # No await between the snapshot and listening: the worker misses no event.
            stop_listening = self.station.listen(self._forward)
            self._process = fork_server().Process(
                target=worker.main, name=f"fleet mission {self.id}", daemon=True,
                args=(child, msgspec.msgpack.encode(start), self.settings.max_memory_mb, self.settings.max_cpu_s),
            )
            self._process.start()
            child.close()
            self._exited = _exit_of(self._process.sentinel)
            done = await self._serve(reader)
            if done is not None:
                self.record = msgspec.structs.replace(done, mission_id=self.id)
            else:
                await self._died()
            return self.record
        except asyncio.CancelledError:
            self._kill("ground_restart", "the ground station stopped")
            raise
        except Exception as exc:  # noqa: BLE001 - a bug here must still end the mission
            log.exception("mission %s: its process failed", self.id)
            self._kill("unexpected", f"{type(exc).__name__}: {exc}")
            await self._died()
            return self.record
        finally:
            stop_listening()
            self._flush_journal()
            for task in self._tasks:
                task.cancel()
            if self._writer is not None:
                self._writer.close()
            else:
                parent.close()
            child.close()
            await self._reap()

    # ---- frames from the worker ----------------------------------------------------

    async def _serve(self, reader: asyncio.StreamReader) -> MissionRecord | None:
        decode = msgspec.msgpack.Decoder(worker.ToGround).decode
        while True:
            try:
                body = await worker.read_frame(reader)
                if body is None:
                    return None
                message = decode(body)
            except (ValueError, msgspec.DecodeError) as exc:  # not our worker's frames: treat it as hostile
                self._kill("security", f"the mission's process sent a malformed message ({exc})")
                return None
            if isinstance(message, worker.Done):
                self._flush_journal()
                return message.record
            if isinstance(message, worker.Resumed):  # its claims first: the calls it makes again follow
                await self._claim(message.held)
                self._retell(message)
                continue
            self._take(message)

    def _take(self, message: Any) -> None:
        if not isinstance(message, worker.Journalled | worker.Active | worker.Ack):
            # Write-ahead: the journal that led the mission here is kept (and goes to
            # the standby grounds) before anything it does reaches the fleet or the
            # log. A ground taking over then replays at least to the mission's last
            # command and log line and makes each again as this one did (same id, same
            # body), never a different decision under an id an agent has answered.
            self._flush_journal()
        if isinstance(message, worker.Changed):
            self._reported = message.record.cause
            record = msgspec.structs.replace(message.record, mission_id=self.id)
            if record.cause is None and self._requested is not None:  # sent before it heard the End: keep showing it
                record.status, record.cause, record.message = self.record.status, self.record.cause, self.record.message
            self.record = record
            self._on_change(self)
        elif isinstance(message, worker.Logged):
            self._on_log(self, message.line)
        elif isinstance(message, worker.Active):
            self.on_activity(self, msgspec.structs.replace(message.activity, mission_id=self.id))
        elif isinstance(message, worker.Call):
            self._spawn(self._answer(message))
        elif isinstance(message, worker.Release):
            registry = self.station.registry
            if message.drone_id in registry and registry.info(message.drone_id).mission == self.id:
                self.station.release(message.drone_id)
        elif isinstance(message, worker.GroundLog):
            self.station.log_ground(message.level, message.message)
        elif isinstance(message, worker.Ack):
            self._acked.set()
        elif isinstance(message, worker.Journalled):
            self._journal.append(message.entry)
            if self._flushing is None:
                self._flushing = asyncio.get_running_loop().call_later(JOURNAL_FLUSH_S, self._flush_journal)

    def _flush_journal(self) -> None:
        if self._flushing is not None:
            self._flushing.cancel()
            self._flushing = None
        if self._journal:
            entries, self._journal = self._journal, []
            self._on_journal(self, "entries", msgspec.msgpack.encode(entries))

    def _retell(self, resumed: worker.Resumed) -> None:
        """What the replay wrote again: the log lines the copy lacks (written on the lost
        ground after its last line reached this one; a replay writes each line as the
        first run did, timestamp included) and every subroutine's activity (the lanes)."""
        assert self._resume is not None
        copied = Counter((line.timestamp, line.level, line.message) for line in self._resume.log)
        for line in resumed.log:
            key = (line.timestamp, line.level, line.message)
            if copied[key] > 0:
                copied[key] -= 1
            else:
                self._on_log(self, line)
        for activity in resumed.activities:
            self.on_activity(self, msgspec.structs.replace(activity, mission_id=self.id))

    async def _claim(self, held: list[str]) -> None:
        """A mission taken over holds here the drones it held on the ground it came from."""
        for drone_id in held:
            try:
                await self.station.assign(drone_id, self.id)
            except Exception as exc:  # noqa: BLE001 - its next verb on the drone says what is wrong
                self._log("warn", f"{drone_id}: not held here after the takeover ({exc})")

    async def _answer(self, call: worker.Call) -> None:
        """Do what the worker asks, as this mission whatever it claims to be."""
        result = b""
        failure = None
        try:
            if call.op == "assign":
                await self.station.assign(call.drone_id, self.id)
            elif call.op == "command":
                result = msgspec.json.encode(await self.station.command(call.drone_id, call.arg, self.id))
            elif call.op == "push":
                result = msgspec.json.encode(await self.station.push(call.drone_id, call.arg, self.id))
            else:
                result = msgspec.json.encode(await self.station.bundle_record(call.drone_id, call.arg.decode()))
        except Exception as exc:  # noqa: BLE001 - every failure goes back to the verb that asked
            if not isinstance(exc, CommandRejected):
                log.debug("mission %s: %s %s failed", self.id, call.op, call.drone_id, exc_info=True)
            failure = worker.failure_of(exc)
        self._send(worker.Reply(call=call.call, result=result, failure=failure))
        if self._resume is not None and call.op == "command" and failure is None:
            self._send_known_statuses(call)

    def _send_known_statuses(self, call: worker.Call) -> None:
        """A mission taken over makes again the calls its journal did not hold; the ground
        it came from may have sent that command already, so the agent answers it as
        before, and its statuses went by before this command was waited on: they follow."""
        command_id = msgspec.json.decode(call.arg).get("command_id")
        if call.drone_id not in self.station.registry:
            return
        for status in self.station.registry.command_statuses(call.drone_id):
            if status.command_id == command_id:
                self._send(worker.Event("status", msgspec.json.encode(status)))

    # ---- events to the worker ------------------------------------------------------

    def _snapshot(self) -> list[worker.Event]:
        registry = self.station.registry
        events = []
        for drone_id in registry.ids():
            events.append(worker.Event("drone", msgspec.json.encode(registry.info(drone_id))))
            events.append(worker.Event("telemetry", msgspec.json.encode(registry.telemetry(drone_id))))
            events += [worker.Event("sensor", msgspec.json.encode(r)) for r in registry.sensor_readings(drone_id)]
        events += [worker.Event("field_sensor", msgspec.json.encode(r)) for r in registry.field_readings()]
        return events

    def _forward(self, event: WatchEvent) -> None:
        if event.kind in worker.EVENT_KINDS:
            self._send(worker.Event(event.kind, msgspec.json.encode(event.data)))

    def _send(self, message: Any) -> None:
        writer = self._writer
        if writer is None or writer.is_closing():
            return
        writer.write(worker.frame(message))
        if writer.transport.get_write_buffer_size() > MAX_BACKLOG:
            self._kill("security", f"the script stopped taking the fleet's events ({MAX_BACKLOG >> 20} MB waiting): "
                                   "one call ran too long")

    # ---- a worker that is stuck or gone --------------------------------------------

    async def _expect_ack(self) -> None:
        try:
            await asyncio.wait_for(self._acked.wait(), STOP_GRACE_S)
        except TimeoutError:
            assert self._requested is not None
            cause, message = self._requested
            self._kill(cause, (message or CAUSES[cause][1]) + "; its script did not stop (one call running in C code), "
                       "so its process was killed")

    def _kill(self, cause: str, message: str) -> None:
        if self._killed is None:
            self._killed = (cause, message)
        if self._process is not None and self._process.exitcode is None:
            with contextlib.suppress(OSError):
                self._process.kill()
        if self._writer is not None:
            self._writer.close()

    async def _died(self) -> None:
        """The worker ended without reporting the mission's end: say why, and do for
        its drones what its end would have."""
        exitcode = await self._exit_code()
        if self._reported is not None:  # it had ended the mission itself, then failed winding down
            cause, message = self._reported, self.record.message or CAUSES[self._reported][1]
        elif self._killed is not None:
            cause, message = self._killed
        elif exitcode == -signal.SIGXCPU:  # RLIMIT_CPU's soft limit: its default action ends it there
            cause, message = "security", f"the script used more than mission.max_cpu_s ({self.settings.max_cpu_s:g} s of CPU)"
        elif exitcode == -signal.SIGKILL:  # not the ground's (that is _killed), not its limits
            cause, message = "unexpected", ("the mission's process was killed (SIGKILL) from outside: the kernel's "
                                            "out-of-memory killer when the machine runs short of memory (see dmesg; "
                                            "lower mission.max_memory_mb), or an operator")
        elif exitcode == worker.MEMORY_EXIT:
            cause, message = "security", f"the script used more than mission.max_memory_mb ({self.settings.max_memory_mb} MB)"
        else:
            cause, message = "unexpected", f"the mission's process ended unexpectedly (exit code {exitcode})"
        await self._conclude(cause, message)

    async def _conclude(self, cause: str, message: str | None) -> None:
        """End the mission here, as `Mission.end` and its wind-down would."""
        self._log(*mark_ended(self.record, cause, message))
        registry = self.station.registry
        for drone_id in registry.ids():
            info = registry.info(drone_id)
            if info.mission == self.id:
                await leave(self.station, self.id, drone_id, critical=CRITICAL_BATTERY in info.errors, log=self._log)
        self.record.active_drones = []
        self.record.end = self.clock.time_ms()
        self._on_change(self)

    def _log(self, level: Literal["info", "warn", "error"], message: str) -> None:
        self._on_log(self, MissionLogLine(timestamp=self.clock.time_ms(), level=level, message=message))

    async def _exit_code(self) -> int | None:
        if self._exited is None:
            return None
        try:
            await asyncio.wait_for(asyncio.shield(self._exited), EXIT_WAIT_S)
        except TimeoutError:
            self._kill(*(self._killed or ("unexpected", "the mission's process did not exit")))
            await self._exited
        return int(self._process.exitcode)

    async def _reap(self) -> None:
        if self._process is None:
            return
        if self._exited is not None and not self._exited.done():
            try:
                await asyncio.wait_for(asyncio.shield(self._exited), EXIT_WAIT_S)
            except (TimeoutError, asyncio.CancelledError):
                self._process.kill()
        if self._exited is not None:
            asyncio.get_running_loop().remove_reader(self._process.sentinel)
        self._process.join(1.0)
        if self._process.exitcode is not None:
            self._process.close()

    def _spawn(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro, name=f"mission {self.id} process")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


def _exit_of(sentinel: int) -> asyncio.Future[None]:
    """Resolved when the process whose sentinel this is has exited."""
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[None] = loop.create_future()

    def readable() -> None:
        loop.remove_reader(sentinel)
        if not fut.done():
            fut.set_result(None)

    loop.add_reader(sentinel, readable)
    return fut
