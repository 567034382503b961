"""Notice when a process's event loop stops turning, and say where it is stuck.

Everything a Fleet process does on the mesh goes through one asyncio loop: the ground
answers the agents' pings, takes telemetry and keeps its registry there; an agent
publishes its telemetry there. A loop blocked for a few seconds looks, from outside,
exactly like a lost radio link (the agents call the ground silent, the ground marks
the drones unknown), so the process says so itself: a thread checks that the loop
has turned within `threshold_s` and, if not, logs a warning with the stack the loop's
thread is in, and the loop itself logs how long it was blocked when it turns again.

The thread needs the GIL to look: code that holds it in C for long (a huge `sum()`,
say) delays or hides the first warning; the second still gives the whole stall.
"""

from __future__ import annotations

import asyncio
import logging
import sys
import threading
import time
import traceback

log = logging.getLogger(__name__)

STALL_S = 1.0  # a loop that has not turned for this long is reported
LOOK_S = 0.5  # how often the watching thread looks (and the loop beats: each a wake-up of an idle agent)


class LoopWatch:
    """Watch the running loop from a daemon thread; `close()` stops it."""

    def __init__(self, name: str, threshold_s: float = STALL_S, period_s: float = LOOK_S) -> None:
        self.name = name
        self.threshold_s = threshold_s
        self.period_s = period_s
        self.longest_s = 0.0  # the longest stall seen, for tests and benches
        self._loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        self._turned = time.monotonic()
        self._stop = threading.Event()
        self._handle: asyncio.TimerHandle | None = None
        self._beat()
        self._thread = threading.Thread(target=self._watch, name=f"{name} loop watch", daemon=True)
        self._thread.start()

    def _beat(self) -> None:
        now = time.monotonic()
        stall = now - self._turned - self.period_s
        if stall > self.threshold_s:  # said here too: the watcher may not have had the GIL
            self.longest_s = max(self.longest_s, stall)
            log.warning("%s: the event loop turned again after %.1f s blocked", self.name, stall)
        self._turned = now
        self._handle = self._loop.call_later(self.period_s, self._beat)

    def _watch(self) -> None:
        reported = 0.0
        while not self._stop.wait(self.period_s):
            turned = self._turned
            lag = time.monotonic() - turned - self.period_s
            if lag > self.threshold_s and reported != turned:  # once per stall
                reported = turned
                log.warning("%s: the event loop has not turned for %.1f s; it is in:\n%s",
                            self.name, lag, self._where())

    def _where(self) -> str:
        frame = sys._current_frames().get(self._loop_thread)
        if frame is None:
            return "  (the loop's thread is gone)"
        return "".join(traceback.format_stack(frame)[-8:]).rstrip()

    def close(self) -> None:
        self._stop.set()
        if self._handle is not None:
            self._handle.cancel()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2 * self.period_s)
