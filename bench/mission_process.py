"""What a mission's own process costs (ADR 0009): how long a submitted mission takes
to start, what one verb takes end to end, and the worker's memory and CPU per event.

    .venv/bin/python bench/mission_process.py [--drones 4] [--missions 10] [--verbs 30]

`fleet ground` and `fleet agent --fc sim` children on loopback, telemetry at 10 Hz.
- start: POST /mission until the record's start (the worker runs the script) (the first one also starts
  the fork server);
- verb: a mission that arms and disarms one drone `--verbs` times; each verb waits
  for the agent's terminal status, so this is the whole loop ground ↔ worker ↔ agent;
- worker: RSS of a mission that waits, and its CPU time per forwarded event over
  a fixed period (every telemetry message of every drone reaches it).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx  # noqa: E402

from bench.procstat import children, cpu_seconds, rss_mib  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from tests.harness import GroundFleet, ended, record, submit  # noqa: E402
from tests.waiting import until


def finished(final: dict[str, Any], what: str) -> dict[str, Any]:
    if final["status"] != "finished":
        raise ScenarioFailed(f"{what} ended {final['status']} ({final['cause']}): {final['message']}")
    return final


async def running(http: httpx.AsyncClient, mission_id: str) -> bool:
    state = await record(http, mission_id)
    assert state["status"] in ("pending", "running"), state
    return state["status"] == "running"


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--drones", type=int, default=4)
    parser.add_argument("--missions", type=int, default=10)
    parser.add_argument("--verbs", type=int, default=30)
    parser.add_argument("--period", type=float, default=20.0, help="seconds the worker's CPU is measured over")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        fcs = {f"drone{i + 1:02d}": f"sim://?lat=40.6334&lon={-8.66081 + 0.00013 * i:.6f}" for i in range(args.drones)}
        fleet = GroundFleet(Path(tmp), fcs, {"telemetry_rate_ms": 100})
        try:
            async with fleet.client() as http:
                starts = []
                for _ in range(args.missions):
                    t0 = time.time() * 1000
                    final = finished(await ended(http, await submit(http, "sleep(0.1*s)\n"), 30), "a start mission")
                    starts.append(final["start"] - t0)  # the record's start: the script's first line
                print(f"start (POST → running): first {starts[0]:.0f} ms (with the fork server), "
                      f"then median {statistics.median(starts[1:]):.0f} ms, max {max(starts[1:]):.0f} ms")

                script = 'd = assign("drone01")\n' + f"for i in range({args.verbs}):\n    arm(d)\n    disarm(d)\n"
                final = finished(await ended(http, await submit(http, script), 120), "the verb mission")
                print(f"verb (arm or disarm to its terminal status, from the script): "
                      f"{(final['end'] - final['start']) / (2 * args.verbs):.1f} ms each over {2 * args.verbs}")

                assert fleet.ground.proc is not None
                ground = fleet.ground.proc.pid
                before = set(children(ground))
                waiting = await submit(http, f"sleep({args.period + 30}*s)\n")
                await until(lambda: running(http, waiting), 30, "the waiting mission")
                workers = [c for server in children(ground) for c in children(server)]
                assert len(workers) == 1, (before, workers)
                worker = workers[0]
                c0, t0 = cpu_seconds(worker), time.monotonic()
                await asyncio.sleep(args.period)  # a bench measures over a period: nothing to wait for
                # The events are counted from the drones' rate, not seen: the worker and every agent must have lasted
                # (checked first: an ended worker's /proc entry is gone).
                state = await record(http, waiting)
                if state["status"] != "running":
                    raise ScenarioFailed(f"the waiting mission ended {state['status']} ({state['cause']}) in the period")
                if dead := [d for d, agent in fleet.agents.items() if agent.proc.poll() is not None]:
                    raise ScenarioFailed(f"agent(s) {', '.join(dead)} exited in the period")
                used, elapsed = cpu_seconds(worker) - c0, time.monotonic() - t0
                events = args.drones * 10 * elapsed
                print(f"worker: RSS {rss_mib(worker):.0f} MB (ground {rss_mib(ground):.0f} MB); CPU {used:.2f} s over "
                      f"{elapsed:.0f} s for ≈{events:.0f} telemetry events = {used / events * 1e6:.0f} µs per event")
                await http.delete(f"/mission/{waiting}")
        finally:
            fleet.stop()


if __name__ == "__main__":
    asyncio.run(main())
