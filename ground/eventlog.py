"""The event log: every registry log line, kept in SQLite so a crash loses none.

One file `events.db` in the data directory, in WAL mode: each line is committed as
it is written, so `kill -9` of the ground keeps everything appended before it, and
readers (the HTTP API, `fleet logs --follow`) never block the writer. Lines read
back in the thesis's text format (example 24):

    2021-01-24 17:04:15,369 INFO drone01 - Registered
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import msgspec

from dronefleet.bus.stream_copy import Stream, unbroken_from
from dronefleet.ground.registry import LogLine

_SCHEMA = """
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    timestamp_ms INTEGER NOT NULL,
    level TEXT NOT NULL CHECK (level IN ('info', 'warn', 'error')),
    drone_id TEXT,
    message TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_drone ON events (drone_id, id);
CREATE TABLE IF NOT EXISTS copies (
    origin TEXT NOT NULL,
    seq INTEGER NOT NULL,
    timestamp_ms INTEGER NOT NULL,
    level TEXT NOT NULL,
    drone_id TEXT,
    message TEXT NOT NULL,
    PRIMARY KEY (origin, seq)
);
"""


def format_line(line: LogLine) -> str:
    seconds, millis = divmod(line.timestamp, 1000)
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(seconds))
    who = f"{line.drone_id} - " if line.drone_id else "- "
    return f"{stamp},{millis:03d} {line.level.upper()} {who}{line.message}"


class EventLog:
    """Append-only log lines in SQLite; used from one thread (the ground's event loop)."""

    def __init__(self, path: Path | str) -> None:
        # each line appended, numbered, for whoever publishes it (SPEC §14: the other grounds copy it)
        self.on_change: Callable[[int, dict[str, Any]], None] = lambda seq, entry: None
        self._db = sqlite3.connect(str(path), isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        # NORMAL in WAL mode: a committed line survives a process crash; only an OS
        # crash or power cut can take back the last few.
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(_SCHEMA)

    def append(self, line: LogLine) -> int:
        cur = self._db.execute(
            "INSERT INTO events (timestamp_ms, level, drone_id, message) VALUES (?, ?, ?, ?)",
            (line.timestamp, line.level, line.drone_id, line.message),
        )
        assert cur.lastrowid is not None
        self.on_change(cur.lastrowid, msgspec.structs.asdict(line))
        return cur.lastrowid

    def query(
        self,
        drone_ids: Sequence[str] = (),
        levels: Sequence[str] = (),
        after_id: int = 0,
        limit: int | None = None,
    ) -> list[tuple[int, LogLine]]:
        """Lines after `after_id`, oldest first, filtered by drone and level (each
        filter matches any of its values; empty = no filter)."""
        sql = "SELECT id, timestamp_ms, level, drone_id, message FROM events WHERE id > ?"
        args: list[object] = [after_id]
        if drone_ids:
            sql += f" AND drone_id IN ({', '.join('?' * len(drone_ids))})"
            args += drone_ids
        if levels:
            sql += f" AND level IN ({', '.join('?' * len(levels))})"
            args += levels
        sql += " ORDER BY id"
        if limit is not None:
            sql += " LIMIT ?"
            args.append(limit)
        return [
            (row[0], LogLine(timestamp=row[1], level=row[2], drone_id=row[3], message=row[4]))
            for row in self._db.execute(sql, args)
        ]

    def keep_copy(self, origin: str, seq: int, line: LogLine) -> bool:
        """Another ground's line `seq` (SPEC §14: a standby keeps the active ground's log);
        False if it was kept already."""
        cur = self._db.execute(
            "INSERT OR IGNORE INTO copies (origin, seq, timestamp_ms, level, drone_id, message) VALUES (?, ?, ?, ?, ?, ?)",
            (origin, seq, line.timestamp, line.level, line.drone_id, line.message),
        )
        return cur.rowcount > 0

    def copied_up_to(self, origin: str, known: int = 0) -> int:
        """The highest line of `origin` kept with every one before it (0: none), looking
        from `known` (a number already known to be kept with all before it) on."""
        rows = self._db.execute("SELECT seq FROM copies WHERE origin = ? AND seq > ? ORDER BY seq", (origin, known))
        return unbroken_from(known, (seq for (seq,) in rows))

    def copies(self, origin: str, after_seq: int = 0, limit: int | None = None) -> list[tuple[int, LogLine]]:
        sql = "SELECT seq, timestamp_ms, level, drone_id, message FROM copies WHERE origin = ? AND seq > ? ORDER BY seq"
        args: list[object] = [origin, after_seq]
        if limit is not None:
            sql += " LIMIT ?"
            args.append(limit)
        return [(row[0], LogLine(timestamp=row[1], level=row[2], drone_id=row[3], message=row[4]))
                for row in self._db.execute(sql, args)]

    def stream(self) -> Stream:
        """The log as a numbered stream the other grounds copy (ground/stream_copy.py)."""
        def after(since: int, limit: int) -> list[tuple[int, dict[str, Any]]]:
            return [(i, msgspec.structs.asdict(x)) for i, x in self.query(after_id=since, limit=limit)]

        def keep(origin: str, seq: int, entry: dict[str, Any]) -> None:
            self.keep_copy(origin, seq, LogLine(timestamp=entry["timestamp"], level=entry["level"],
                                                drone_id=entry.get("drone_id"), message=entry["message"]))

        return Stream("log", after, keep, self.copied_up_to)

    def origins(self) -> list[str]:
        return [r[0] for r in self._db.execute("SELECT DISTINCT origin FROM copies ORDER BY origin")]

    def last_id(self) -> int:
        row = self._db.execute("SELECT MAX(id) FROM events").fetchone()
        return int(row[0] or 0)

    def close(self) -> None:
        self._db.close()
