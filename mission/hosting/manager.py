"""The mission manager: submit, run, cancel and remember missions (thesis §5.2.2).

Records (SPEC §4 / table 5.1) and their log lines live in SQLite (`missions.db` in the
data directory, WAL, one commit per change), so a ground that restarts still lists
every mission; ones that were running when it died are marked failed with cause
`ground_restart`. Every change is also broadcast to the station's watchers as a
`mission` event (the dashboard and `fleet mission submit --watch`).
"""

from __future__ import annotations

import asyncio
import base64
import builtins
import itertools
import json
import logging
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

from dronefleet.bus.clock import Clock
from dronefleet.bus.stream_copy import Stream, unbroken_from
from dronefleet.mission.hosting import worker
from dronefleet.mission.hosting.isolation import IsolatedMission, Resume
from dronefleet.mission.hosting.journal import Entry
from dronefleet.mission.lifecycle.fleet_port import GroundPort
from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.lifecycle.record import Activity, CommandResult, MissionLogLine, MissionRecord, mark_ended
from dronefleet.mission.script.checks import first_problem
from dronefleet.mission.script.plugins import PluginLibrary
from dronefleet.mission.script.sandbox import compile_mission
from dronefleet.mission.script.script import ScriptMission
from dronefleet.schemas.errors import FleetError
from dronefleet.schemas.fleet import WatchEvent

log = logging.getLogger(__name__)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS missions (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    mission_id TEXT UNIQUE NOT NULL,
    record TEXT NOT NULL,
    source TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS mission_log (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    mission_id TEXT NOT NULL,
    timestamp_ms INTEGER NOT NULL,
    level TEXT NOT NULL,
    message TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS mission_log_mission ON mission_log (mission_id, id);
CREATE TABLE IF NOT EXISTS mission_changes (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    mission_id TEXT NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('record', 'line', 'start', 'entries')),
    body TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS mission_copies (
    origin TEXT NOT NULL,
    seq INTEGER NOT NULL,
    mission_id TEXT NOT NULL,
    kind TEXT NOT NULL,
    body TEXT NOT NULL,
    PRIMARY KEY (origin, seq)
);
"""
# Before journals (ADR 0017) mission_changes took records and lines only.
_MIGRATE_CHANGES = """
ALTER TABLE mission_changes RENAME TO mission_changes_old;
CREATE TABLE mission_changes (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    mission_id TEXT NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('record', 'line', 'start', 'entries')),
    body TEXT NOT NULL
);
INSERT INTO mission_changes (seq, mission_id, kind, body) SELECT seq, mission_id, kind, body FROM mission_changes_old;
DROP TABLE mission_changes_old;
"""
_record_decoder = msgspec.json.Decoder(MissionRecord)
_start_decoder = msgspec.msgpack.Decoder(worker.Start)
_entries_decoder = msgspec.msgpack.Decoder(list[Entry])
_line_decoder = msgspec.json.Decoder(MissionLogLine)
Running = Mission | IsolatedMission


class UnknownMission(FleetError, KeyError):
    """No mission with that id (HTTP 404)."""


class MissionEnded(FleetError):
    """Cancelling a mission that already ended (HTTP 409)."""


class MissionStore:
    """SQLite persistence of records and log lines; ':memory:' for simulations.

    Every change (a record as it now is, a line of a log) is also numbered in
    `mission_changes`, the stream the other grounds on the mesh copy (SPEC §14;
    `on_change(seq, entry)` tells whoever publishes it), and their copies of another
    ground's changes are kept in `mission_copies`."""

    def __init__(self, path: Path | str) -> None:
        self.on_change: Callable[[int, dict[str, Any]], None] = lambda seq, entry: None
        self._db = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
        if str(path) != ":memory:":
            self._db.execute("PRAGMA journal_mode=WAL")
        self._db.executescript(_SCHEMA)
        made = self._db.execute("SELECT sql FROM sqlite_master WHERE name = 'mission_changes'").fetchone()[0]
        if "'entries'" not in made:
            self._db.executescript("BEGIN;" + _MIGRATE_CHANGES + "COMMIT;")

    def close(self) -> None:
        self._db.close()

    def next_id(self) -> str:
        row = self._db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM missions").fetchone()
        return f"m{row[0]}"

    def create(self, record: MissionRecord, source: str) -> None:
        body = msgspec.json.encode(record).decode()
        self._db.execute("INSERT INTO missions (mission_id, record, source) VALUES (?, ?, ?)",
                         (record.mission_id, body, source))
        self._changed(record.mission_id, "record", body)

    def save(self, record: MissionRecord) -> None:
        body = msgspec.json.encode(record).decode()
        self._db.execute("UPDATE missions SET record = ? WHERE mission_id = ?", (body, record.mission_id))
        self._changed(record.mission_id, "record", body)

    def append(self, mission_id: str, line: MissionLogLine) -> None:
        self._db.execute(
            "INSERT INTO mission_log (mission_id, timestamp_ms, level, message) VALUES (?, ?, ?, ?)",
            (mission_id, line.timestamp, line.level, line.message),
        )
        self._changed(mission_id, "line", msgspec.json.encode(line).decode())

    def journal(self, mission_id: str, kind: str, body: bytes) -> None:
        """A mission's journal (kind `start`: its worker's Start; `entries`: a batch of
        Entry), numbered with its other changes: the standby grounds copy it in order."""
        self._changed(mission_id, kind, base64.b64encode(body).decode())

    def _changed(self, mission_id: str, kind: str, body: str) -> None:
        cur = self._db.execute("INSERT INTO mission_changes (mission_id, kind, body) VALUES (?, ?, ?)",
                               (mission_id, kind, body))
        assert cur.lastrowid is not None
        self.on_change(cur.lastrowid, {"mission_id": mission_id, "kind": kind, "body": body})

    def last_change(self) -> int:
        return int(self._db.execute("SELECT COALESCE(MAX(seq), 0) FROM mission_changes").fetchone()[0])

    def stream(self) -> Stream:
        """The missions' changes as a numbered stream the other grounds copy."""
        def after(since: int, limit: int) -> list[tuple[int, dict[str, Any]]]:
            rows = self._db.execute("SELECT seq, mission_id, kind, body FROM mission_changes WHERE seq > ? ORDER BY seq "
                                    "LIMIT ?", (since, limit))
            return [(seq, {"mission_id": m, "kind": k, "body": b}) for seq, m, k, b in rows]

        def keep(origin: str, seq: int, entry: dict[str, Any]) -> None:
            self._db.execute("INSERT OR IGNORE INTO mission_copies (origin, seq, mission_id, kind, body) "
                             "VALUES (?, ?, ?, ?, ?)", (origin, seq, entry["mission_id"], entry["kind"], entry["body"]))

        def copied_up_to(origin: str, known: int) -> int:
            rows = self._db.execute("SELECT seq FROM mission_copies WHERE origin = ? AND seq > ? ORDER BY seq",
                                    (origin, known))
            return unbroken_from(known, (seq for (seq,) in rows))

        return Stream("missions", after, keep, copied_up_to)

    def copied_records(self, origin: str) -> list[MissionRecord]:
        """Another ground's missions as this ground's copy last saw each."""
        rows = self._db.execute(
            "SELECT body FROM mission_copies WHERE origin = ? AND kind = 'record' AND seq IN "
            "(SELECT MAX(seq) FROM mission_copies WHERE origin = ? AND kind = 'record' GROUP BY mission_id) "
            "ORDER BY mission_id", (origin, origin)).fetchall()
        return [_record_decoder.decode(r[0]) for r in rows]

    def copied_journal(self, origin: str, mission_id: str, upto: int) -> tuple[worker.Start | None, list[Entry]]:
        """Another ground's mission's Start and journal as far as this copy is whole
        (entries numbered up to `upto`)."""
        rows = self._db.execute("SELECT kind, body FROM mission_copies WHERE origin = ? AND mission_id = ? AND "
                                "kind IN ('start', 'entries') AND seq <= ? ORDER BY seq", (origin, mission_id, upto))
        start: worker.Start | None = None
        entries: list[Entry] = []
        for kind, body in rows:
            if kind == "start":
                start = _start_decoder.decode(base64.b64decode(body))
            else:
                entries += _entries_decoder.decode(base64.b64decode(body))
        return start, entries

    def copied_log(self, origin: str, mission_id: str) -> list[MissionLogLine]:
        rows = self._db.execute("SELECT body FROM mission_copies WHERE origin = ? AND mission_id = ? AND kind = 'line' "
                                "ORDER BY seq", (origin, mission_id)).fetchall()
        return [_line_decoder.decode(r[0]) for r in rows]

    def get(self, mission_id: str) -> MissionRecord | None:
        row = self._db.execute("SELECT record FROM missions WHERE mission_id = ?", (mission_id,)).fetchone()
        return _record_decoder.decode(row[0]) if row else None

    def source(self, mission_id: str) -> str | None:
        row = self._db.execute("SELECT source FROM missions WHERE mission_id = ?", (mission_id,)).fetchone()
        return row[0] if row else None

    def all(self) -> list[MissionRecord]:
        rows = self._db.execute("SELECT record FROM missions ORDER BY seq").fetchall()
        return [_record_decoder.decode(r[0]) for r in rows]

    def log(self, mission_id: str) -> list[MissionLogLine]:
        rows = self._db.execute(
            "SELECT timestamp_ms, level, message FROM mission_log WHERE mission_id = ? ORDER BY id", (mission_id,)
        ).fetchall()
        return [MissionLogLine(timestamp=t, level=lvl, message=msg) for t, lvl, msg in rows]


LANES_KEPT = 50
MARKS_KEPT = 500


class Lanes(msgspec.Struct, kw_only=True):
    """`GET /mission/{id}`'s `subroutines` (the latest activity of each, in the order
    they started) and `marks` (what its plugins' subroutines did, oldest first)."""

    subroutines: dict[str, Activity] = msgspec.field(default_factory=dict)
    marks: list[Activity] = msgspec.field(default_factory=list)

    def take(self, activity: Activity) -> None:
        self.subroutines[activity.subroutine] = activity
        if activity.plugin is not None and activity.event == "verb":
            self.marks.append(activity)
            del self.marks[:-MARKS_KEPT]


class MissionManager:
    def __init__(
        self,
        station: GroundPort,
        store: MissionStore,
        clock: Clock,
        *,
        deterministic: bool = False,
        seed: int | None = None,
        plugins: PluginLibrary | None = None,
        isolate: bool = False,
        check_commanding: Callable[[], None] = lambda: None,
    ) -> None:
        """With `isolate`, every mission runs in a process of its own under the limits
        `mission.max_memory_mb` and `mission.max_cpu_s` (the ground; ADR 0009);
        without, on this loop (fast-time simulation, where the clock is virtual)."""
        self.station = station
        self.isolate = isolate
        # SPEC §14: raises NotCommanding while this ground does not command (the station's)
        self.check_commanding = check_commanding
        self.plugins = plugins
        self.store = store
        self.clock = clock
        self.deterministic = deterministic
        self.seed = seed
        self._running: dict[str, tuple[Running, asyncio.Task[MissionRecord]]] = {}
        self._seeds = itertools.count(seed or 0)
        self.commands: list[CommandResult] = []  # every mission's verbs, for simulation results
        self.echo: Callable[[str, MissionLogLine], None] | None = None  # progress printing
        # A prediction's host (the preflight): told what each mission read that it cannot know
        self.on_unknowable: Callable[[Mission, int | None, str], None] | None = None
        self._lanes: dict[str, Lanes] = {}  # mission id → what its subroutines last did (the newest LANES_KEPT)
        self._recover()

    def _recover(self) -> None:
        for record in self.store.all():
            if record.status in ("pending", "running"):
                self._fail_unrun(record, "ground_restart")

    def _fail_unrun(self, record: MissionRecord, cause: str, message: str | None = None) -> None:
        """End a mission this ground will not run, as any mission ends (`mark_ended`):
        its record saved and the line that says so logged."""
        level, line = mark_ended(record, cause, message)
        record.end = record.end or self.clock.time_ms()
        record.active_drones = []
        self.store.save(record)
        self.store.append(record.mission_id, MissionLogLine(timestamp=self.clock.time_ms(), level=level, message=line))

    # ---- operations ----------------------------------------------------------------

    def submit(self, source: str, name: str = "", enable: dict[str, dict[str, Any]] | None = None,
               submitted_by: str | None = None, notes: builtins.list[str] | None = None) -> MissionRecord:
        """Check and compile (ScriptError → 400 with line/column), record as pending, start.

        `enable` maps plugin ids to inputs, enabled before the script's first line
        (`fleet mission simulate --enable`); `notes` are its log's first lines (the
        preflight's prediction). NotCommanding on a ground that does not command."""
        self.check_commanding()
        mission_id = self.store.next_id()
        first_problem(source, f"<mission {mission_id}>", self.plugins.verbs() if self.plugins is not None else ())
        code = compile_mission(source, filename=f"<mission {mission_id}>")
        record = MissionRecord(mission_id=mission_id, name=name, submitted_by=submitted_by)
        self.store.create(record, source)
        for note in notes or []:
            self.store.append(mission_id, MissionLogLine(timestamp=self.clock.time_ms(), level="info", message=note))
        if submitted_by is not None:  # the audit trail (SPEC §9)
            self.station.log_ground("info", f"Mission {mission_id} submitted by {submitted_by}")
        mission: Running
        if self.isolate:
            mission = IsolatedMission(record, source, self.station, self.clock, on_change=self._on_change,
                                      on_log=self._on_log, plugins=self.plugins, enable=enable,
                                      on_journal=self._on_journal)
        else:
            mission = ScriptMission(
                record, code, self.station, self.clock,
                deterministic=self.deterministic, seed=next(self._seeds) if self.seed is not None else None,
                on_change=self._on_change, on_log=self._on_log, plugins=self.plugins, enable=enable,
            )
            mission.commands = self.commands
        self.station.log_ground("info", f"Mission {mission_id} submitted" + (f" ({name})" if name else ""))
        self._start(mission)
        return msgspec.structs.replace(record)

    def _start(self, mission: Running) -> None:
        mission.on_activity = self._on_activity
        if isinstance(mission, Mission):  # an isolated mission is never a prediction
            mission.on_unknowable = self.on_unknowable
        task = asyncio.get_running_loop().create_task(self._run(mission), name=f"mission {mission.id}")
        self._running[mission.id] = (mission, task)
        self._broadcast(mission.record)

    def take_over(self, origin: str, upto: int) -> builtins.list[MissionRecord]:
        """Go on with the missions that ground `origin` (lost) was running, each from its
        journal as this ground's copy holds it whole (changes numbered up to `upto`):
        replayed in a process of its own, then live (SPEC §14). Each runs here as
        `<origin>-<its id>`; one whose journal did not reach this ground ends at once
        with cause `ground_lost`. Returns the records taken over."""
        taken = []
        for copied in self.store.copied_records(origin):
            if copied.status not in ("pending", "running"):
                continue
            mission_id = f"{origin}-{copied.mission_id}"
            if self.store.get(mission_id) is not None:
                continue
            start, entries = self.store.copied_journal(origin, copied.mission_id, upto)
            record = msgspec.structs.replace(copied, mission_id=mission_id, submitted_as=copied.submitted_as or copied.mission_id)
            source = start.source if start is not None else ""
            self.store.create(record, source)
            copied_log = self.store.copied_log(origin, copied.mission_id)
            for line in copied_log:
                self.store.append(mission_id, line)
            if start is None or not self.isolate:
                why = f"ground {origin} was lost and its journal of mission {copied.mission_id} did not reach this ground"
                self._fail_unrun(record, "ground_lost", why)
                self._broadcast(record)
                taken.append(record)
                continue
            self.store.append(mission_id, MissionLogLine(
                timestamp=self.clock.time_ms(), level="warn",
                message=f"Mission {copied.mission_id} of ground {origin} goes on here as {mission_id}: "
                        f"{len(entries)} journal entries replayed, then live"))
            self.station.log_ground("warn", f"Mission {copied.mission_id} of lost ground {origin} taken over as {mission_id}")
            self._start(IsolatedMission(record, source, self.station, self.clock, on_change=self._on_change,
                                        on_log=self._on_log, plugins=self.plugins, on_journal=self._on_journal,
                                        resume=Resume(start, entries, copied_log)))
            taken.append(record)
        return taken

    async def _run(self, mission: Running) -> MissionRecord:
        try:
            return await mission.run()
        finally:
            self._running.pop(mission.id, None)
            r = mission.record
            self.station.log_ground(
                "info" if r.status == "finished" else "warn", f"Mission {r.mission_id} {r.status}: {r.cause}"
            )

    def cancel(self, mission_id: str, cause: str = "user", message: str | None = None) -> MissionRecord:
        self.check_commanding()
        mission_id = self.resolve(mission_id)
        entry = self._running.get(mission_id)
        # A record with its end has ended, even while its task finishes (a mission's own
        # process reports the end before it exits).
        if entry is None or entry[0].record.end is not None:
            if self.store.get(mission_id) is None:
                raise UnknownMission(mission_id)
            raise MissionEnded(f"mission {mission_id} already ended")
        entry[0].end(cause, message)
        return msgspec.structs.replace(entry[0].record)

    def resolve(self, mission_id: str) -> str:
        """The id a mission runs under here: `mission_id` itself, or the mission taken over
        from a lost ground that was submitted there as `mission_id` (the newest such)."""
        if mission_id in self._running or self.store.get(mission_id) is not None:
            return mission_id
        taken = [r.mission_id for r in self.store.all() if r.submitted_as == mission_id]
        return taken[-1] if taken else mission_id

    def get(self, mission_id: str) -> MissionRecord:
        mission_id = self.resolve(mission_id)
        entry = self._running.get(mission_id)
        if entry is not None:
            return msgspec.structs.replace(entry[0].record)
        record = self.store.get(mission_id)
        if record is None:
            raise UnknownMission(mission_id)
        return record

    def list(self) -> builtins.list[MissionRecord]:
        return [self.get(r.mission_id) if r.mission_id in self._running else r for r in self.store.all()]

    def log(self, mission_id: str) -> builtins.list[MissionLogLine]:
        record = self.get(mission_id)
        return self.store.log(record.mission_id)

    async def wait(self, mission_id: str) -> MissionRecord:
        entry = self._running.get(mission_id)
        if entry is not None:
            return await asyncio.shield(entry[1])
        return self.get(mission_id)

    async def close(self) -> None:
        """Stop every running mission (cause ground_restart) and wait for its clean-up."""
        for mission, _ in list(self._running.values()):
            mission.end("ground_restart")
        tasks = [task for _, task in self._running.values()]
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)

    # ---- persistence and events ----------------------------------------------------

    def _on_change(self, mission: Running) -> None:
        self.store.save(mission.record)
        self._broadcast(mission.record)

    def _on_journal(self, mission: IsolatedMission, kind: str, body: bytes) -> None:
        self.store.journal(mission.id, kind, body)

    def _on_log(self, mission: Running, line: MissionLogLine) -> None:
        self.store.append(mission.id, line)
        if self.echo is not None:
            self.echo(mission.id, line)
        log.log(
            {"info": logging.INFO, "warn": logging.WARNING, "error": logging.ERROR}[line.level],
            "mission %s - %s", mission.id, line.message,
        )
        self.station.broadcast(WatchEvent("mission_log", {"mission_id": mission.id, **msgspec.to_builtins(line)}))

    def _on_activity(self, mission: Running, activity: Activity) -> None:
        lanes = self._lanes.get(mission.id)
        if lanes is None:
            lanes = self._lanes[mission.id] = Lanes()
            while len(self._lanes) > LANES_KEPT:
                del self._lanes[next(iter(self._lanes))]
        lanes.take(activity)
        self.station.broadcast(WatchEvent("subroutine", msgspec.to_builtins(activity)))

    def lanes(self, mission_id: str) -> Lanes:
        """What each subroutine of the mission last did, and its plugins' actions (empty
        for a mission this ground did not run)."""
        return self._lanes.get(mission_id) or Lanes()

    def _broadcast(self, record: MissionRecord) -> None:
        self.station.broadcast(WatchEvent("mission", json.loads(msgspec.json.encode(record))))
