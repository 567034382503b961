"""The bundle runner (SPEC §6): a drone works through a task bundle on its own.

Each command step goes through the same CommandHandler as a command from the ground
(`submit`: same validation, same priority rules), with the command id
`<bundle_id>/<step>`; the runner follows it by the statuses the handler emits. Guards
are checked every GUARD_POLL_S against the drone's own telemetry and the latest
readings of its on-board sensors: a step's `until` ends that step (the drone holds,
the next step starts), the bundle's `until` ends the bundle. Nothing here needs the
ground: progress goes out as BundleStatus and into the BundleRecord, which the store
keeps on disk so a ground that was out of range — or an agent restarted mid-bundle —
finds out what happened.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import msgspec

from dronefleet.agent.handler import CommandHandler
from dronefleet.bus.clock import Clock
from dronefleet.schemas.bundles import (
    Bundle,
    BundleEvent,
    BundleRecord,
    BundleReply,
    BundleStatus,
    Guard,
    Step,
    StepEvent,
    describe_guard,
)
from dronefleet.schemas.commands import Cancel, Command, Return
from dronefleet.schemas.status import CommandStatus
from dronefleet.schemas.telemetry import Telemetry

log = logging.getLogger(__name__)
GUARD_POLL_S = 0.1
KEEP_RECORDS = 100  # the store forgets the oldest finished records beyond this
DONE_STATES = frozenset({"finish", "success"})
FAILED_STATES = frozenset({"failure", "cancel", "stop"})


class BundleStore:
    """The agent's bundle records, written through to `path` (JSON) when it is set."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.records: dict[str, BundleRecord] = {}
        if path is not None and path.exists():
            try:
                raw = json.loads(path.read_text())
                self.records = {r["bundle_id"]: msgspec.convert(r, BundleRecord) for r in raw}
            except (OSError, ValueError, msgspec.ValidationError) as exc:
                log.error("bundle records in %s are unreadable (%s); starting with none", path, exc)

    def get(self, bundle_id: str) -> BundleRecord | None:
        return self.records.get(bundle_id)

    def put(self, record: BundleRecord) -> None:
        self.records[record.bundle_id] = record
        finished = [r for r in self.records.values() if r.finished]
        for old in sorted(finished, key=lambda r: r.started)[: max(0, len(self.records) - KEEP_RECORDS)]:
            del self.records[old.bundle_id]
        self.save()

    def save(self) -> None:
        if self.path is None:
            return
        tmp = self.path.with_suffix(".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_bytes(msgspec.json.encode(list(self.records.values())))
            os.replace(tmp, self.path)  # a crash leaves the old file or the new one
        except OSError as exc:
            log.error("cannot write bundle records to %s: %s", self.path, exc)


class BundleRunner:
    def __init__(
        self,
        drone_id: str,
        handler: CommandHandler,
        clock: Clock,
        emit: Callable[[BundleStatus], None],
        telemetry: Callable[[], Telemetry | None],
        store: BundleStore,
    ) -> None:
        self.drone_id = drone_id
        self.handler = handler
        self.clock = clock
        self.emit = emit
        self.telemetry = telemetry
        self.store = store
        self.sensors: dict[str, Any] = {}  # latest on-board reading per type
        self.current: Bundle | None = None
        self._task: asyncio.Task[None] | None = None
        self._commands: dict[str, asyncio.Future[CommandStatus]] = {}
        self._taken: dict[str, bytes] = {}  # per bundle accepted since start: its content (`_content`)

    # ---- start-up: bundles a previous run left unfinished ----------------------------

    def recover(self) -> None:
        for record in list(self.store.records.values()):
            if record.state == "running":
                record.state, record.reason, record.ended = "failed", "the agent restarted mid-bundle", self.clock.time_ms()
                self._emit(record.bundle_id, record.step, "failure", record.reason, record.steps, record=record)
                log.warning("%s: bundle %s was running when the agent stopped: failed", self.drone_id, record.bundle_id)

    # ---- from the agent --------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    @property
    def on_link_loss(self) -> str | None:
        return self.current.on_link_loss if self.running and self.current is not None else None

    def submit(self, bundle: Bundle) -> BundleReply:
        """Start `bundle`. The same bundle again (its id and content, whenever and however
        signed: the ground sends it again when no answer came) is answered as accepted
        before, with its state, and not run twice; another bundle under a known id is
        refused."""
        known = self.store.get(bundle.bundle_id)
        if known is not None:
            if self._taken.get(bundle.bundle_id) == _content(bundle):
                return BundleReply(bundle_id=bundle.bundle_id, accepted=True,
                                   reason=f"bundle {bundle.bundle_id} accepted before ({known.state})")
            return BundleReply(bundle_id=bundle.bundle_id, accepted=False, reason=f"bundle {bundle.bundle_id} exists already ({known.state})")
        if not self.handler.connected:
            return BundleReply(bundle_id=bundle.bundle_id, accepted=False, reason="flight controller disconnected")
        if self.running:
            self.interrupt(f"superseded by bundle {bundle.bundle_id}")
        record = BundleRecord(bundle_id=bundle.bundle_id, state="running", steps=len(bundle.steps), started=self.clock.time_ms())
        self.store.put(record)
        self._taken[bundle.bundle_id] = _content(bundle)
        self.current = bundle
        self._task = asyncio.get_running_loop().create_task(self._run(bundle, record), name=f"bundle {bundle.bundle_id}")
        log.info("%s: bundle %s accepted (%d steps, on link loss: %s)", self.drone_id, bundle.bundle_id, len(bundle.steps), bundle.on_link_loss)
        return BundleReply(bundle_id=bundle.bundle_id, accepted=True)

    def interrupt(self, reason: str) -> None:
        """A command (or bundle) from the ground takes over: the bundle is cancelled."""
        self._stop("cancelled", "cancel", reason)

    def end_for_link_loss(self) -> str | None:
        """The link to the ground is lost: a bundle whose policy is hold or return ends
        and the drone does that (returned: the action taken), `continue` goes on."""
        policy = self.on_link_loss
        if policy is None or policy == "continue":
            return None
        self._stop("ended", "guard", f"link lost (on_link_loss={policy})", ended_by="link_lost")
        command = (Cancel if policy == "hold" else Return)(drone_id=self.drone_id, command_id=f"{self._bundle_id}/{policy}", timestamp=self.clock.time_ms())
        self.handler.submit(command)
        return policy

    def on_status(self, status: CommandStatus) -> None:
        """Every status the handler emits: completes the step that sent the command."""
        future = self._commands.get(status.command_id)
        if future is None or future.done():
            return
        if status.state in DONE_STATES or status.state in FAILED_STATES:
            future.set_result(status)

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    # ---- running ---------------------------------------------------------------------

    @property
    def _bundle_id(self) -> str:
        return self.current.bundle_id if self.current is not None else "?"

    def _values(self) -> Callable[[str], Any]:
        """The drone as it is now — one telemetry snapshot, the latest sensor readings —
        as the lookup every guard of one poll reads its fields from."""
        telemetry = self.telemetry()
        sensors = dict(self.sensors)

        def value(field: str) -> Any:
            if field.startswith("sensor."):  # sensor.<type> or, declared with fields, sensor.<type>.<field>
                kind, _, name = field.removeprefix("sensor.").partition(".")
                reading = sensors.get(kind)
                if name:
                    return reading.get(name) if isinstance(reading, dict) else None
                return None if isinstance(reading, dict) else reading
            found: Any = telemetry
            for part in field.split("."):
                found = getattr(found, part, None)
                if found is None:
                    return None
            return found

        return value

    @staticmethod
    def _guard_hit(guard: Guard | None, values: Callable[[str], Any]) -> str | None:
        return describe_guard(guard, values) if guard is not None and guard.holds(values) else None

    async def _run(self, bundle: Bundle, record: BundleRecord) -> None:
        n = len(bundle.steps)
        deadline = self.clock.monotonic() + bundle.timeout_s if bundle.timeout_s is not None else None
        try:
            for i, step in enumerate(bundle.steps):
                record.step = i
                self._emit(bundle.bundle_id, i, "start", None, n, step.name, record=record)
                outcome, detail = await self._step(bundle, i, step, deadline)
                if outcome == "done":
                    record.steps_done += 1
                    self._emit(bundle.bundle_id, i, "finish", None, n, step.name, record=record)
                elif outcome == "step_guard":
                    record.steps_done += 1
                    self._emit(bundle.bundle_id, i, "guard", detail, n, step.name, record=record)
                    log.info("%s: bundle %s step %d/%d ended by %s", self.drone_id, bundle.bundle_id, i + 1, n, detail)
                elif outcome == "bundle_guard":
                    self._finish(record, "ended", "guard", detail, ended_by=detail)
                    return
                elif outcome == "timeout":
                    self._finish(record, "failed", "failure", f"timeout: not done within {bundle.timeout_s:g} s")
                    return
                else:
                    self._finish(record, "failed", "failure", f"step {i}: {detail}")
                    return
            self._finish(record, "done", "done", None)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # a bug must not leave the record "running"
            log.exception("%s: bundle %s crashed", self.drone_id, bundle.bundle_id)
            self._finish(record, "failed", "failure", f"internal error: {exc}")

    async def _step(self, bundle: Bundle, i: int, step: Step, deadline: float | None) -> tuple[str, str | None]:
        """("done"|"step_guard"|"bundle_guard"|"timeout"|"failed", detail)."""
        command_id = f"{bundle.bundle_id}/{i}"
        future: asyncio.Future[CommandStatus] | None = None
        if step.command is not None:
            future = asyncio.get_running_loop().create_future()
            self._commands[command_id] = future
            command: Command = msgspec.structs.replace(step.command, drone_id=self.drone_id, command_id=command_id, timestamp=self.clock.time_ms())
            reply = self.handler.submit(command)
            if not reply.accepted:
                self._commands.pop(command_id, None)
                return "failed", f"{step.name} refused: {reply.reason}"
        wait_until = self.clock.monotonic() + step.wait_s if step.wait_s is not None else None
        try:
            while True:
                values = self._values()
                hit = self._guard_hit(bundle.until, values)
                if hit is not None:
                    self._end_command(future)
                    return "bundle_guard", hit
                hit = self._guard_hit(step.until, values)
                if hit is not None:
                    self._end_command(future)
                    return "step_guard", hit
                if deadline is not None and self.clock.monotonic() >= deadline:
                    self._hold()
                    return "timeout", None
                if future is not None and future.done():
                    status = future.result()
                    if status.state in DONE_STATES:
                        return "done", None
                    return "failed", f"{step.name} {status.state}" + (f": {status.reason}" if status.reason else "")
                if wait_until is not None and self.clock.monotonic() >= wait_until:
                    return "done", None
                await self.clock.sleep(GUARD_POLL_S)
        finally:
            self._commands.pop(command_id, None)

    def _end_command(self, future: asyncio.Future[CommandStatus] | None) -> None:
        """A guard ended the step: a command still running there is stopped (the drone
        holds). Its cancel status resolves a future nobody reads any more."""
        if future is not None and not future.done():
            self._hold()

    def _hold(self) -> None:
        self.handler.submit(Cancel(drone_id=self.drone_id, command_id=f"{self._bundle_id}/hold", timestamp=self.clock.time_ms()))

    def _stop(self, state: str, event: BundleEvent, reason: str, ended_by: str | None = None) -> None:
        if not self.running or self.current is None:
            return
        assert self._task is not None
        self._task.cancel()
        record = self.store.get(self.current.bundle_id)
        if record is not None:
            self._finish(record, state, event, reason, ended_by=ended_by)

    def _finish(self, record: BundleRecord, state: str, event: BundleEvent, reason: str | None, ended_by: str | None = None) -> None:
        record.state = state  # type: ignore[assignment]
        record.reason = reason if state in ("failed", "cancelled") else None
        record.ended_by = ended_by
        record.ended = self.clock.time_ms()
        self._emit(record.bundle_id, record.step, event, reason, record.steps, record=record,
                   scope="bundle" if event == "guard" else None)
        log.info("%s: bundle %s %s at step %d/%d%s", self.drone_id, record.bundle_id, state, record.step + 1, record.steps,
                 f": {reason}" if reason else "")

    def _emit(self, bundle_id: str, step: int, state: BundleEvent, reason: str | None, steps: int | None = None,
              command: str | None = None, *, record: BundleRecord, scope: Literal["bundle"] | None = None) -> None:
        """Publish one event and keep it in the record (written through to disk first)."""
        record.history.append(StepEvent(step=step, state=state, timestamp=self.clock.time_ms(), reason=reason, scope=scope))
        self.store.put(record)
        self.emit(BundleStatus(drone_id=self.drone_id, timestamp=self.clock.time_ms(), bundle_id=bundle_id, step=step,
                               state=state, reason=reason, scope=scope, steps=steps, command=command))


def _content(bundle: Bundle) -> bytes:
    """What a bundle asks, not when or by whom it was sent (its timestamp and signature
    differ each time the ground sends it)."""
    wire = msgspec.structs.replace(bundle.wire, timestamp=0, auth=None)
    return hashlib.blake2b(msgspec.json.encode(wire), digest_size=16).digest()
