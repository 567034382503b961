"""The event log across grounds (SPEC §14, replicated state): the active ground publishes
every line it logs on `ground/<id>/log` (numbered as in its own log) and answers
`ground/<id>/log?since=<seq>` with the lines after `seq`; every other ground keeps a copy
in its own SQLite (`EventLog.keep_copy`). A copy catches up by query when it starts
hearing a ground, and whenever a line's number shows one was missed (a gap, a lossy
moment): nothing the active ground logged is missing on the standby once its lines
could cross the mesh.
"""

from __future__ import annotations

import asyncio
import logging

import msgspec

from dronefleet.bus.port import Bus, BusError, Declaration, Sample
from dronefleet.ground.eventlog import EventLog
from dronefleet.ground.registry import LogLine
from dronefleet.schemas.grounds import GroundLogLine
from dronefleet.schemas.keys import Keys

log = logging.getLogger(__name__)

PAGE = 1000  # lines per catch-up answer


_line = msgspec.json.Decoder(GroundLogLine)
_page = msgspec.json.Decoder(list[GroundLogLine])


class LogCopy:
    def __init__(self, bus: Bus, keys: Keys, events: EventLog, ground_id: str) -> None:
        self.bus = bus
        self.keys = keys
        self.events = events
        self.me = ground_id
        self._catching: dict[str, asyncio.Task[None]] = {}
        self._upto: dict[str, int] = {}  # per origin: the highest line kept with all before it

    def declare(self) -> list[Declaration]:
        return [self.bus.serve(self.keys.ground(self.me, "log"), self._answer),
                self.bus.subscribe(self.keys.ground("*", "log"), self._on_line, maxsize=65_536)]

    def upto(self, origin: str) -> int:
        if origin not in self._upto:
            self._upto[origin] = self.events.copied_up_to(origin)
        return self._upto[origin]

    def heard_active(self, origin: str, log_seq: int) -> None:
        """The active ground says it has logged `log_seq` lines: catch up if behind."""
        if origin != self.me and log_seq > self.upto(origin):
            self.catch_up(origin)

    def published(self, seq: int, line: LogLine) -> None:
        """A line this ground just logged (and numbered `seq`): out to the others."""
        self.bus.publish(self.keys.ground(self.me, "log"), msgspec.json.encode(GroundLogLine(
            seq=seq, timestamp=line.timestamp, level=line.level, drone_id=line.drone_id, message=line.message)))

    def catch_up(self, origin: str) -> None:
        """Ask `origin` for every line after the last one kept in order (once at a time)."""
        if origin == self.me or origin in self._catching:
            return
        task = asyncio.get_running_loop().create_task(self._catch_up(origin), name=f"log copy of {origin}")
        self._catching[origin] = task
        task.add_done_callback(lambda _: self._catching.pop(origin, None))

    def close(self) -> None:
        for task in list(self._catching.values()):
            task.cancel()

    async def _answer(self, selector: str, payload: bytes) -> bytes:
        params = dict(p.split("=", 1) for p in selector.partition("?")[2].split(";") if "=" in p)
        since = int(params.get("since", "0") or 0)
        lines = self.events.query(after_id=since, limit=PAGE)
        return msgspec.json.encode([GroundLogLine(seq=i, timestamp=x.timestamp, level=x.level, drone_id=x.drone_id,
                                               message=x.message) for i, x in lines])

    def _on_line(self, sample: Sample) -> None:
        origin = sample.key.split("/")[-2]
        if origin == self.me:
            return
        try:
            line = _line.decode(sample.payload)
        except msgspec.MsgspecError:
            return
        before = self.upto(origin)
        self._keep(origin, line)
        if line.seq > before + 1:  # lines were missed (or this ground joined late): ask for them
            self.catch_up(origin)

    def _keep(self, origin: str, line: GroundLogLine) -> None:
        self.events.keep_copy(origin, line.seq, LogLine(timestamp=line.timestamp, level=line.level,  # type: ignore[arg-type]
                                                        drone_id=line.drone_id, message=line.message))
        if line.seq == self.upto(origin) + 1:
            self._upto[origin] = self.events.copied_up_to(origin, known=line.seq)

    async def _catch_up(self, origin: str) -> None:
        while True:
            since = self.upto(origin)
            try:
                page = _page.decode(await self.bus.query(f"{self.keys.ground(origin, 'log')}?since={since}", timeout_s=3.0))
            except (BusError, msgspec.MsgspecError) as exc:
                log.info("the log of ground %s could not be caught up from %d (%s): the next line asks again",
                         origin, since, exc)
                return
            for line in page:
                self._keep(origin, line)
            if len(page) < PAGE:
                return
