"""Test helpers: free ports, waiting on conditions with a deadline, collectors."""

from __future__ import annotations

import asyncio
import inspect
import signal
import socket
import subprocess
import time
from collections.abc import Callable
from typing import Any


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def signal_and_wait(proc: subprocess.Popen[Any], sig: int, timeout_s: float, name: str = "process") -> int:
    """Send `sig` and wait for the exit; past `timeout_s` kill it (a test never leaves
    one behind) and fail."""
    proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"{name} did not stop within {timeout_s:g} s on {signal.Signals(sig).name}") from None


async def until(predicate: Callable[[], Any], timeout_s: float, what: str = "condition") -> Any:
    """Wait until predicate() (plain or async) is truthy, re-checked at most every
    20 ms, and return its value; fail with `what` when the deadline passes."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if inspect.isawaitable(value):
            value = await value
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        await asyncio.sleep(0.02)


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


def free_udp_base(n: int) -> int:
    """A base port B with B-1 .. B+n-1 free for UDP (the sim's control port and vehicles)."""
    for _ in range(50):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            base = s.getsockname()[1]
        if base + n >= 65000:
            continue
        try:
            held = []
            for port in range(base - 1, base + n):
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                held.append(sock)
                sock.bind(("127.0.0.1", port))
            return base
        except OSError:
            continue
        finally:
            for sock in held:
                sock.close()
    raise RuntimeError("no free UDP port range")
