"""CPU and memory of a process from /proc (Linux): the measuring half of the benchmarks."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

_TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICKS  # utime + stime


def children(pid: int) -> list[int]:
    """The processes whose parent is `pid`."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:  # it ended while we looked
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


@dataclass
class Usage:
    cpu_percent: float  # of one core
    rss_mib: float
    window_s: float


class Window:
    """CPU share over a wall-clock window: start(), then stop() later."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self._t0 = time.monotonic()
        self._c0 = cpu_seconds(pid)

    def stop(self) -> Usage:
        elapsed = time.monotonic() - self._t0
        used = cpu_seconds(self.pid) - self._c0
        return Usage(100 * used / elapsed, rss_mib(self.pid), elapsed)
