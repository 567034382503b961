"""A mission's journal: everything it took in, in the order and at the mission time it
took it, so that another ground can run it again to the same point (SPEC §14, durable
missions; ADR 0017).

A mission in its own process (`mission.worker`) runs on a `VirtualClock` that this
module's `Driver` moves, and its greenlets slice their work by count, not by time
(`Scheduler`'s deterministic mode): what it does is then a function of its inputs
alone, as in a fast-time simulation. Its inputs are the frames the ground sends it —
the fleet's events, the answers to its calls, an end — and the mission time each was
taken in. The driver takes one at a time, only when the mission has nothing left to
do at the time it stands at:

- live, it waits for whichever comes first, the next frame or the next sleeper's
  deadline on the wall clock; a frame is journalled with the mission time it is taken
  at, then the clock moves there (waking every sleeper due before, one deadline at a
  time) and the frame is delivered; a deadline only wakes its sleepers (time is not an
  input: it follows from the frames' times);
- in replay, it takes the journal's frames at their times instead, and nothing the
  mission does goes out (its calls are answered by the journalled replies).

Reads of the fleet (telemetry, sensors, channels, `now`) are answered from what those
frames built up, so a replay reads what the original read, and each subroutine resumes
in the same order.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterable
from typing import Generic, TypeVar

import msgspec

from dronefleet.bus.clock import VirtualClock

M = TypeVar("M")


class Entry(msgspec.Struct, array_like=True, frozen=True):
    """One frame the mission took (`frame`: the ground's msgpack frame body, as it came)
    and the mission time it took it at (seconds since the mission started)."""

    t_s: float
    frame: bytes


def mission_clock(started_ms: int) -> VirtualClock:
    """The clock a journalled mission runs on: 0 at its start, `time_ms()` the wall
    time it started at plus the mission time."""
    return VirtualClock(start_s=0.0, epoch_ms=started_ms)


async def quiet() -> None:
    """Run the loop until nothing is ready: the mission has done all it can at this
    mission time (a script computing yields every slice and is ready again, so this
    returns once it waits on a verb or a sleep)."""
    loop = asyncio.get_running_loop()
    ready = getattr(loop, "_ready", None)  # CPython's run queue
    while True:
        await asyncio.sleep(0)
        if ready is None or not ready:
            return


class Driver(Generic[M]):
    """Moves a journalled mission's clock and hands it its frames, one at a time, as
    messages: live frames come decoded once by whoever read them, with their bytes
    for the journal; a replay's are decoded with `decode`."""

    def __init__(self, clock: VirtualClock, deliver: Callable[[M], None], decode: Callable[[bytes], M],
                 record: Callable[[Entry], None] = lambda entry: None) -> None:
        self.clock = clock
        self._deliver = deliver
        self._decode = decode
        self._record = record

    async def _wake_next(self) -> None:
        """Wake the sleepers due next and let the mission do all it then can."""
        self.clock.wake_next()
        await quiet()

    async def _take(self, entry: Entry, message: M) -> None:
        """The clock to the entry's time, one deadline at a time, then its frame. Each
        step runs the loop until it is quiet, however many rounds that takes: a bounded
        settle would end early or late as other callbacks (the socket's) come and go."""
        while (deadline := self.clock.next_deadline()) is not None and deadline <= entry.t_s:
            await self._wake_next()
        self.clock.move_to(entry.t_s)
        self._deliver(message)
        await quiet()

    async def replay(self, entries: Iterable[Entry]) -> None:
        """Take the journal's frames again, at their times."""
        await quiet()
        for entry in entries:
            await self._take(entry, self._decode(entry.frame))

    async def live(self, frames: asyncio.Queue[tuple[bytes, M] | None]) -> None:
        """Take the frames as they come, each as its bytes and its message (None: the
        ground is gone), and wake sleepers on
        the wall clock; each frame is journalled before the mission sees it. Mission
        time is the wall time since the mission started (`clock.time_ms()` at 0): after
        a takeover it goes on from the time the mission has really been running."""
        clock = self.clock
        origin = time.monotonic() - (time.time() * 1000 - clock.epoch_ms) / 1000  # monotonic() at mission time 0
        await quiet()
        while True:
            deadline = clock.next_deadline()
            wait_s = None if deadline is None else deadline - (time.monotonic() - origin)
            if wait_s is not None and wait_s <= 0:
                await self._wake_next()
                continue
            try:
                taken = await asyncio.wait_for(frames.get(), wait_s)
            except TimeoutError:
                continue
            if taken is None:
                return
            body, message = taken
            entry = Entry(max(clock.monotonic(), time.monotonic() - origin), body)
            self._record(entry)
            await self._take(entry, message)
