"""A ground's numbered record kept by the other grounds (SPEC §14, replicated state).

The active ground publishes each entry of a record it keeps numbered — its event log,
its missions' changes — on `ground/<id>/<stream>` as `{"seq": n, ...}`, and answers
`ground/<id>/<stream>?since=<n>` with the entries after `n`; every other ground keeps a
copy in its own SQLite. A copy asks for what it missed whenever an entry's number shows
a gap, and when the active ground's announcement says its record is longer than the
copy (a ground that joined late): nothing the active ground recorded is missing on a
standby once its entries could cross the mesh.

A `Stream` says where the entries come from and where copies go; `StreamCopy` carries
them over the mesh.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import msgspec

from dronefleet.bus.port import Bus, BusError, Declaration, Sample
from dronefleet.schemas.keys import Keys

log = logging.getLogger(__name__)

PAGE = 1000  # entries per catch-up answer

Entry = dict[str, Any]  # an entry's fields, its number aside


@dataclass(frozen=True)
class Stream:
    name: str  # the last chunk of its key: ground/<id>/<name>
    after: Callable[[int, int], list[tuple[int, Entry]]]  # this ground's entries after a number (at most a page)
    keep: Callable[[str, int, Entry], None]  # a copy of another ground's entry
    copied_up_to: Callable[[str, int], int]  # the highest kept with every one before it, from a known one on


def unbroken_from(known: int, seqs: Iterable[int]) -> int:
    """The highest of `seqs` (ascending, all above `known`) reached from `known` with no
    number missing: how far a copy is whole (entries are numbered from 1 with no holes
    on the ground that wrote them)."""
    upto = known
    for seq in seqs:
        if seq != upto + 1:
            break
        upto = seq
    return upto


_entry = msgspec.json.Decoder(dict[str, Any])
_page = msgspec.json.Decoder(list[dict[str, Any]])


class StreamCopy:
    def __init__(self, bus: Bus, keys: Keys, ground_id: str, stream: Stream) -> None:
        self.bus = bus
        self.keys = keys
        self.me = ground_id
        self.stream = stream
        self._catching: dict[str, asyncio.Task[None]] = {}
        self._upto: dict[str, int] = {}  # per origin: the highest entry kept with all before it

    def declare(self) -> list[Declaration]:
        return [self.bus.serve(self.keys.ground(self.me, self.stream.name), self._answer),
                self.bus.subscribe(self.keys.ground("*", self.stream.name), self._on_entry, maxsize=65_536)]

    def published(self, seq: int, entry: Entry) -> None:
        """An entry this ground just recorded as `seq`: out to the others."""
        self.bus.publish(self.keys.ground(self.me, self.stream.name), msgspec.json.encode({"seq": seq, **entry}))

    def upto(self, origin: str) -> int:
        if origin not in self._upto:
            self._upto[origin] = self.stream.copied_up_to(origin, 0)
        return self._upto[origin]

    def heard_active(self, origin: str, last_seq: int) -> None:
        """The active ground says its record ends at `last_seq`: catch up if behind."""
        if origin != self.me and last_seq > self.upto(origin):
            self.catch_up(origin)

    def catch_up(self, origin: str) -> None:
        """Ask `origin` for every entry after the last one kept in order (once at a time)."""
        if origin == self.me or origin in self._catching:
            return
        task = asyncio.get_running_loop().create_task(self._catch_up(origin), name=f"{self.stream.name} copy of {origin}")
        self._catching[origin] = task
        task.add_done_callback(lambda _: self._catching.pop(origin, None))

    def close(self) -> None:
        for task in list(self._catching.values()):
            task.cancel()

    async def _answer(self, selector: str, payload: bytes) -> bytes:
        params = dict(p.split("=", 1) for p in selector.partition("?")[2].split(";") if "=" in p)
        since = int(params.get("since", "0") or 0)
        return msgspec.json.encode([{"seq": seq, **entry} for seq, entry in self.stream.after(since, PAGE)])

    def _on_entry(self, sample: Sample) -> None:
        origin = sample.key.split("/")[-2]
        if origin == self.me:
            return
        try:
            entry = _entry.decode(sample.payload)
            seq = int(entry.pop("seq"))
        except (msgspec.MsgspecError, KeyError, TypeError, ValueError):
            return
        before = self.upto(origin)
        self._keep(origin, seq, entry)
        if seq > before + 1:  # entries were missed (or this ground joined late): ask for them
            self.catch_up(origin)

    def _keep(self, origin: str, seq: int, entry: Entry) -> None:
        self.stream.keep(origin, seq, entry)
        if seq == self.upto(origin) + 1:
            self._upto[origin] = self.stream.copied_up_to(origin, seq)

    async def _catch_up(self, origin: str) -> None:
        while True:
            since = self.upto(origin)
            selector = f"{self.keys.ground(origin, self.stream.name)}?since={since}"
            try:
                page = _page.decode(await self.bus.query(selector, timeout_s=3.0))
            except (BusError, msgspec.MsgspecError) as exc:
                log.info("the %s of ground %s could not be caught up from %d (%s): the next entry asks again",
                         self.stream.name, origin, since, exc)
                return
            for entry in page:
                self._keep(origin, int(entry.pop("seq")), entry)
            if len(page) < PAGE:
                return
