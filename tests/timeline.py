"""The suite's schedule from a FLEET_TEST_TIMELINE file (tests/conftest.py): per worker,
how busy it was and when it ended, with its tests of 5 s or more (start and length);
then what the tests cost in CPU (the most first) and the longest setups (a setup that
waits is a test waiting on a host lock, such as a radio slot another run holds).
`python -m tests.timeline FILE`."""

from __future__ import annotations

import sys
from collections import defaultdict


def main(path: str) -> None:
    spans: dict[tuple[str, str], list[float]] = {}
    setup: dict[str, float] = {}
    cpu: dict[str, float] = {}
    for line in open(path, encoding="utf-8"):
        worker, when, start, stop, nodeid = line.split(" ", 4)
        if when == "cpu":
            cpu[nodeid.strip()] = float(start)
            continue
        key = (worker, nodeid.strip())
        span = spans.setdefault(key, [float(start), float(stop)])
        span[0], span[1] = min(span[0], float(start)), max(span[1], float(stop))
        if when == "setup":
            setup[nodeid.strip()] = float(stop) - float(start)
    t0 = min(s for s, _ in spans.values())
    end = max(e for _, e in spans.values())
    by_worker: dict[str, list[tuple[float, float, str]]] = defaultdict(list)
    for (worker, nodeid), (s, e) in spans.items():
        by_worker[worker].append((s - t0, e - t0, nodeid))
    print(f"suite: {end - t0:.0f} s from the first test's start to the last one's end")
    for worker in sorted(by_worker):
        runs = sorted(by_worker[worker])
        busy = sum(e - s for s, e, _ in runs)
        print(f"\n{worker}: {len(runs)} tests, busy {busy:.0f} s, ends at {runs[-1][1]:.0f} s")
        for s, e, nodeid in runs:
            if e - s >= 5:
                print(f"  {s:6.0f} +{e - s:5.0f}  {nodeid}")
    if cpu:
        print(f"\nCPU: {sum(cpu.values()):.0f} s in all (the tests' workers and the processes they reaped); the most:")
        for nodeid, c in sorted(cpu.items(), key=lambda kv: -kv[1])[:20]:
            print(f"  {c:6.1f}  {nodeid}")
    print("\nlongest setups:")
    for nodeid, d in sorted(setup.items(), key=lambda kv: -kv[1])[:8]:
        print(f"  {d:6.1f}  {nodeid}")


if __name__ == "__main__":
    main(sys.argv[1])
