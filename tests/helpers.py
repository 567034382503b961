"""Test helpers: free ports, waiting on conditions with a deadline, collectors."""

from __future__ import annotations

import asyncio
import inspect
import itertools
import os
import random
import signal
import socket
import subprocess
import time
from collections.abc import Callable
from typing import Any

# Radio tests at once on this host (tests/radio/'s `radio_slot`), each a
# ground, a `fleet sim` and an agent per drone.
# With four at once beside the rest of `make test` on two cores, every drone of one run
# lost the ground together for ~10 s, twice, and a command to a drone 55 m out went
# unanswered for 3 s (full-suite runs of 2026-11-23, before the mesh fix of issue 30);
# each passes alone. Two at once held in 15 fresh-clone runs (5 beside CPU burners).
# Three, with eight workers, saturated both cores from the second minute on and a
# radio run went void (its ground stand-in's loop blocked 0.5 s): 2026-11-24.
RADIO_SLOTS = 2


def _ephemeral_low() -> int:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def _worker_slice() -> range:
    """This xdist worker's own share of the ports below the kernel's ephemeral range.

    Asking the kernel for port 0 gives a port from the range it also uses for every
    other port-0 listener (each agent's router) and every outgoing connection's local
    port, so a port a test chose and freed (a killed ground restarted on the same port)
    could be taken before it was bound again. Below that range only tests choose, and
    each worker from its own slice."""
    low, high = 15000, _ephemeral_low()  # above the MAVLink ports the sim defaults to (14540…)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    size = (high - low) // count
    return range(low + index * size, low + (index + 1) * size)


_ports = _worker_slice()
_next_port = itertools.count(random.randrange(len(_ports)))  # runs of one worker rarely meet


def free_ports(n: int, kind: socket.SocketKind = socket.SOCK_STREAM) -> int:
    """The first of `n` consecutive ports free on 127.0.0.1 for `kind`, never handed
    out twice by this process while the slice lasts."""
    for _ in range(len(_ports)):
        base = _ports[0] + next(_next_port) % len(_ports)
        if base + n > _ports[-1] + 1:
            continue
        held: list[socket.socket] = []
        try:
            for port in range(base, base + n):
                sock = socket.socket(socket.AF_INET, kind)
                held.append(sock)
                sock.bind(("127.0.0.1", port))
            for _ in range(n - 1):
                next(_next_port)
            return base
        except OSError:
            continue
        finally:
            for sock in held:
                sock.close()
    raise RuntimeError(f"no {n} free ports in {_ports}")


def free_port() -> int:
    return free_ports(1)


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


def free_udp_base(n: int) -> int:
    """A base port B with B-1 .. B+n-1 free for UDP (the sim's control port and vehicles)."""
    return free_ports(n + 1, socket.SOCK_DGRAM) + 1


async def advance_until(sim: Any, predicate: Callable[[], Any], max_s: float) -> None:
    """Move a fast-time field's virtual clock (`sim.clock`, a SimField's) in 0.1 s steps
    until `predicate()` holds; fail after `max_s` simulated seconds."""
    for _ in range(round(max_s * 10)):
        if predicate():
            return
        await sim.clock.advance(0.1)
    raise AssertionError(f"not within {max_s:g} simulated seconds")
