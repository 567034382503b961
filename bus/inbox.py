"""Hand-off from a transport into the event loop through one bounded queue.

Both bus adapters deliver samples through an Inbox: the transport side calls `put`
(thread-safe), a named pump task owned by the inbox calls the handler on the loop.
A latest-only inbox drops the oldest sample when full; a normal one keeps all up to
its bound and logs each sample it must drop.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Generic, TypeVar

log = logging.getLogger(__name__)
T = TypeVar("T")


class Inbox(Generic[T]):
    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        handler: Callable[[T], None],
        *,
        name: str,
        latest_only: bool = False,
        maxsize: int = 1024,
    ) -> None:
        self._loop = loop
        self._handler = handler
        self._name = name
        self._latest_only = latest_only
        self._queue: asyncio.Queue[T] = asyncio.Queue(maxsize=max(1, maxsize))
        self._closed = False
        self._task = loop.create_task(self._pump(), name=f"inbox {name}")

    def put(self, item: T) -> None:
        """Thread-safe; never blocks the caller (a transport thread)."""
        if self._closed:
            return
        try:
            self._loop.call_soon_threadsafe(self._enqueue, item)
        except RuntimeError:  # loop closed while the transport still delivers
            self._closed = True

    def put_nowait(self, item: T) -> None:
        """Same, from the loop's own thread."""
        if not self._closed:
            self._enqueue(item)

    def _enqueue(self, item: T) -> None:
        if self._queue.full():
            dropped = self._queue.get_nowait()
            if not self._latest_only:
                log.error("inbox %s full: dropped %r (consumer too slow)", self._name, dropped)
        self._queue.put_nowait(item)

    async def _pump(self) -> None:
        while True:
            item = await self._queue.get()
            try:
                self._handler(item)
            except Exception:
                log.exception("handler of %s failed", self._name)

    def close(self) -> None:
        self._closed = True
        self._task.cancel()
