"""Injected time: the system clock for real runs, a virtual clock for tests and fast-time.

Code asks a Clock for `monotonic()` (seconds, for durations), `time_ms()` (wall time
for message timestamps) and `sleep()`. VirtualClock only moves when `advance()` is
called, so ten minutes of flight run in milliseconds and replay identically.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import math
import time
from collections.abc import Callable
from typing import Protocol


class Clock(Protocol):
    def monotonic(self) -> float: ...

    def time_ms(self) -> int: ...

    async def sleep(self, seconds: float) -> None: ...


class SystemClock:
    def monotonic(self) -> float:
        return time.monotonic()

    def time_ms(self) -> int:
        return time.time_ns() // 1_000_000

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(seconds)


class VirtualClock:
    """Time that advances only on request; sleepers wake in deadline order."""

    def __init__(self, start_s: float = 0.0, epoch_ms: int = 1_700_000_000_000) -> None:
        self._now = start_s
        self._epoch_ms = epoch_ms
        self._timers: list[tuple[float, int, asyncio.Future[None] | Callable[[], None]]] = []
        self._seq = itertools.count()

    def monotonic(self) -> float:
        return self._now

    def time_ms(self) -> int:
        return self._epoch_ms + int(round(self._now * 1000))

    async def sleep(self, seconds: float) -> None:
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        heapq.heappush(self._timers, (self._now + max(0.0, seconds), next(self._seq), fut))
        await fut

    def call_later(self, seconds: float, callback: Callable[[], None]) -> None:
        """Run `callback` when virtual time reaches now + seconds (a message in flight):
        at that instant it joins the loop's queue where a woken sleeper would."""
        heapq.heappush(self._timers, (self._now + max(0.0, seconds), next(self._seq), callback))

    @property
    def epoch_ms(self) -> int:
        """The wall time (ms) virtual time 0 stands for."""
        return self._epoch_ms

    def next_deadline(self) -> float | None:
        """When the earliest sleeper or callback is due (None: nothing waits on time)."""
        return self._timers[0][0] if self._timers else None

    def wake_next(self) -> float | None:
        """Move to the earliest deadline and wake what is due then, no more: nothing runs
        until the caller yields (mission/hosting/journal.py lets the loop run until it is
        quiet, then wakes the next). Returns that deadline, or None if nothing waits."""
        if not self._timers:
            return None
        deadline = self._timers[0][0]
        self._now = max(self._now, deadline)
        self._wake(deadline)
        return deadline

    def _wake(self, deadline: float) -> None:
        """Wake every sleeper due at `deadline`: a callback joins the loop's queue where a
        woken sleeper would."""
        loop = asyncio.get_running_loop()
        while self._timers and self._timers[0][0] == deadline:
            _, _, due = heapq.heappop(self._timers)
            if not isinstance(due, asyncio.Future):
                loop.call_soon(due)
            elif not due.done():
                due.set_result(None)

    def move_to(self, t_s: float) -> None:
        """Set the time forward to `t_s` with nothing due before it (wake_next first)."""
        assert not self._timers or self._timers[0][0] > t_s, "a sleeper is due before the time moved to"
        self._now = max(self._now, t_s)

    async def advance(self, seconds: float) -> None:
        """Move time forward, waking each sleeper at its deadline and letting it run.

        Sleepers due at the same instant wake together, then the loop runs until
        nothing is ready before time moves on: the order of events is a function of
        the deadlines alone, so a simulation replays identically.
        """
        target = self._now + seconds
        await _settle()
        while self._timers and self._timers[0][0] <= target:
            deadline = self._timers[0][0]
            self._now = max(self._now, deadline)
            self._wake(deadline)
            await _settle()
        self._now = target
        await _settle()


def until_next_tick_s(now_s: float, period_s: float) -> float:
    """Seconds from `now_s` to the next multiple of `period_s`: loops that tick on this
    grid wake together under a VirtualClock (one settle of the loop for all of them,
    not one each at its own phase) and the same instants replay from the same start."""
    tick = math.floor(now_s / period_s + 1e-6) + 1
    return max(0.0, tick * period_s - now_s)


async def _settle(max_rounds: int = 64) -> None:
    """Let chains of call_soon / task wake-ups run until the loop has nothing ready."""
    loop = asyncio.get_running_loop()
    ready = getattr(loop, "_ready", None)  # CPython's run queue; absent: fixed rounds
    for i in range(max_rounds):
        await asyncio.sleep(0)
        if ready is not None and not ready:
            return
        if ready is None and i >= 7:
            return
