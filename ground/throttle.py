"""Warnings about what the mesh sends, kept readable under a flood (issue 31).

A key that floods the ground with bad messages must not flood its log: per key, the
first `burst` warnings of a window are logged as they come, the rest are counted, and
the key's next warning after the window says how many were held back. Nothing is
hidden: the line that starts the holding says so, and the count comes with the next.
"""

from __future__ import annotations

import logging

from dronefleet.bus.clock import Clock

WINDOW_MS = 10_000
BURST = 10
MAX_KEYS = 1024  # distinct keys remembered; beyond, the oldest windows are forgotten


class WarningThrottle:
    def __init__(self, log: logging.Logger, clock: Clock, window_ms: int = WINDOW_MS, burst: int = BURST) -> None:
        self.log, self.clock, self.window_ms, self.burst = log, clock, window_ms, burst
        self._windows: dict[str, tuple[int, int]] = {}  # key -> (window start, warnings in it)
        self._held: dict[str, int] = {}

    def warn(self, key: str, message: str, *args: object) -> None:
        now = self.clock.time_ms()
        start, count = self._windows.get(key, (now, 0))
        if now - start >= self.window_ms:
            start, count = now, 0
        count += 1
        self._remember(key, start, count)
        if count > self.burst:
            self._held[key] = self._held.get(key, 0) + 1
            return
        held = self._held.pop(key, 0)
        if held:
            message += " (%d more on this key held back before this one)"
            args = (*args, held)
        if count == self.burst:
            message += " (further warnings on this key are counted for %g s)"
            args = (*args, self.window_ms / 1000)
        self.log.warning(message, *args)

    def _remember(self, key: str, start: int, count: int) -> None:
        self._windows.pop(key, None)
        self._windows[key] = (start, count)  # most recent last
        while len(self._windows) > MAX_KEYS:
            oldest = next(iter(self._windows))
            del self._windows[oldest]
            self._held.pop(oldest, None)
