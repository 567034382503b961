"""Whether this Zenoh session's router holds a route to a key's queryable, for many keys
at a bounded cost (the ground's watch on every drone's command queryable, issue 76).

A querier's matching status is the router's own lookup for a `get` on its key: no
query is sent to learn it. Zenoh can push its changes (a matching listener), but a
listener costs about 18 KiB and 0.5 ms to declare, and makes every queryable declared
on the mesh about seven times slower to take in (5000 listeners: 99 MiB; measured in
one process, zenoh 1.10). A querier alone costs 2.3 KiB and its status 36 µs to read,
so the watches are polled instead: the unrouted ones (a drone that just registered, or
lost its route) every POLL_S for their first FAST_FOR_S (an id nobody serves, say a
made-up one, then costs what a routed one does), the routed ones a slice per poll so that each is read at
least every SWEEP_S, and all of them at the next poll after a link of this session
closes (a route may have gone with it), at most every CLOSED_SWEEP_MIN_S: a full read
of 5000 costs 180 ms of the event loop. A link that opens brings routes to the
unrouted ones, which are read every poll anyway.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import zenoh

POLL_S = 0.2
SWEEP_S = 5.0
FAST_FOR_S = 10.0  # an unrouted watch is read every POLL_S this long, then with the sweep
CLOSED_SWEEP_MIN_S = 1.0  # after links close, every watch is read at most this often


def matching(status: object) -> bool:
    """A querier's `matching_status`: a `MatchingStatus` at run time, though zenoh-python
    1.10's stub says `bool`."""
    return bool(getattr(status, "matching", status))


class RouteWatch:
    def __init__(self, querier: zenoh.Querier, handler: Callable[[bool], None]) -> None:
        self.querier, self.handler = querier, handler
        self.routed = matching(querier.matching_status)
        self.since = time.monotonic()  # when `routed` last changed
        self.closed = False

    def check(self) -> None:
        routed = matching(self.querier.matching_status)
        if routed != self.routed and not self.closed:
            self.routed, self.since = routed, time.monotonic()
            self.handler(routed)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.querier.undeclare()


class RouteWatches:
    """Every route watch of one session, read on the event loop."""

    def __init__(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        self._session, self._loop = session, loop
        self._watches: list[RouteWatch] = []
        self._cursor = 0
        self._all_next = False
        self._all_read_at = -math.inf
        self._task: asyncio.Task[None] | None = None
        self._links: zenoh.LinkEventsListener | None = None

    def watch(self, key: str, handler: Callable[[bool], None]) -> RouteWatch:
        watch = RouteWatch(self._session.declare_querier(key), handler)
        self._watches.append(watch)
        if self._task is None:
            self._links = self._session.info.declare_link_events_listener(self._on_link)
            self._task = self._loop.create_task(self._poll(), name="route watches")
        handler(watch.routed)
        return watch

    def _on_link(self, event: zenoh.LinkEvent) -> None:  # on a Zenoh thread
        if event.kind != zenoh.SampleKind.DELETE:
            return
        try:
            self._loop.call_soon_threadsafe(self._check_all_next)
        except RuntimeError:  # loop closed
            pass

    def _check_all_next(self) -> None:
        self._all_next = True

    async def _poll(self) -> None:
        while True:
            await asyncio.sleep(POLL_S)
            self._watches = [w for w in self._watches if not w.closed]
            if not self._watches:
                continue
            if self._all_next and time.monotonic() - self._all_read_at >= CLOSED_SWEEP_MIN_S:
                self._all_next, self._all_read_at = False, time.monotonic()
                due = list(self._watches)
            else:
                n = len(self._watches)
                share = math.ceil(n * POLL_S / SWEEP_S)
                start = self._cursor % n
                self._cursor = start + share
                sweep = self._watches[start:start + share] + self._watches[:max(0, start + share - n)]
                swept, recent = set(sweep), time.monotonic() - FAST_FOR_S
                due = sweep + [w for w in self._watches if not w.routed and w.since > recent and w not in swept]
            for watch in due:
                watch.check()

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        if self._links is not None:
            self._links.undeclare()
        for watch in self._watches:
            watch.close()
        self._watches.clear()
