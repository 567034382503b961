"""Waiting in tests, always with a deadline: on a condition (`until`), on what a handler
received (`Collector`, an event per item), on a fast-time field's virtual clock
(`advance_until`)."""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Callable
from typing import Any


async def until(predicate: Callable[[], Any], timeout_s: float, what: str = "condition") -> Any:
    """Wait until predicate() (plain or async) is truthy and return its value; fail
    with `what` when the deadline passes. It is re-checked every 20 ms at first, then
    less often as the wait grows (a tenth of the time waited so far, at most 0.2 s):
    a long wait on the ground's API (a mission to end, a drone out of range) would
    otherwise make 250 HTTP requests a second, most of a core on 2 (the relay radio
    test spent 37 CPU-seconds in the suite, 18 with this)."""
    start = time.monotonic()
    deadline = start + timeout_s
    while True:
        value = predicate()
        if inspect.isawaitable(value):
            value = await value
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        await asyncio.sleep(min(0.2, max(0.02, (time.monotonic() - start) / 10)))


class Collector:
    """Records what a handler receives and lets a test wait for a match."""

    def __init__(self) -> None:
        self.items: list[Any] = []
        self._changed = asyncio.Event()

    def __call__(self, *args: Any) -> None:
        self.items.append(args[0] if len(args) == 1 else args)
        self._changed.set()

    async def wait_for(
        self, predicate: Callable[[Any], bool], timeout_s: float = 5.0, what: str = "item", start: int = 0
    ) -> Any:
        """The first item from index `start` on that matches, waiting up to timeout_s."""
        deadline = time.monotonic() + timeout_s
        seen = start
        while True:
            for item in self.items[seen:]:
                if predicate(item):
                    return item
            seen = len(self.items)
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}; got {self.items[-5:]}")
            self._changed.clear()
            try:
                async with asyncio.timeout(remaining):
                    await self._changed.wait()
            except TimeoutError:
                pass


async def advance_until(sim: Any, predicate: Callable[[], Any], max_s: float) -> None:
    """Move a fast-time field's virtual clock (`sim.clock`, a SimField's) in 0.1 s steps
    until `predicate()` holds; fail after `max_s` simulated seconds."""
    for _ in range(round(max_s * 10)):
        if predicate():
            return
        await sim.clock.advance(0.1)
    raise AssertionError(f"not within {max_s:g} simulated seconds")
