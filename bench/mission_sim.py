"""Mission runtime figures: fast-time speed-up, verb overhead, subroutine cost.

    .venv/bin/python bench/mission_sim.py [--verbs 1000]

(a) Speed-up: a ten-minute, four-drone patrol (each drone laps a 100 m square at
    5 m/s, concurrently, until 600 simulated seconds have passed) under
    `mission.simulate`'s virtual clock; simulated seconds per wall second. Target ≥ 100.
(b) Verb overhead: wall time from a script calling `arm(drone)` until the agent's
    command queryable receives it (runtime → station checks → bus), p50/p99 over
    --verbs calls, on the in-process memory bus; the Zenoh hop on top is measured by
    bench/ground_command.py (bare get → agent accept).
(c) Subroutines: memory and start time per subroutine for 200 and 2000 sleeping
    subroutines in one mission.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.agent.runtime import Agent  # noqa: E402
from dronefleet.compose import SimField, simulate  # noqa: E402
from dronefleet.mission.script import script as script_mission  # noqa: E402
from dronefleet.schemas.geo import destination  # noqa: E402
from dronefleet.sim.world import DroneSpec, World  # noqa: E402

SPEEDUP_TARGET = 100  # (a), simulated seconds per wall second

PATROL = """
def patrol(d):
    arm(d)
    takeoff(d, 10*m)
    while True:
        for _ in range(4):
            move(d, forward=100*m)
            turn(d, by=90*deg)

drones = assign(any_drone, any_drone, any_drone, any_drone)
patrols = [run(patrol, d) for d in drones]
sleep(600*s)
stop(*patrols)
wait(*patrols)
wait(*[run(land, d) for d in drones])
"""


def patrol_world() -> World:
    """Four drones 40 m apart on an east-west line: their 100 m squares never bring two
    within the deconfliction distance of each other's targets."""
    home_lat, home_lon = 40.6334, -8.6608
    return World(drones=[DroneSpec(id=f"drone{i + 1:02d}", lat=home_lat, lon=destination(home_lat, home_lon, 40.0 * i, 90.0)[1])
                         for i in range(4)])


async def speedup() -> None:
    t0 = time.perf_counter()
    result = await simulate(PATROL, patrol_world(), seed=1, plots=False)
    wall = time.perf_counter() - t0
    record = result["mission"]
    if (record["status"], record["cause"]) != ("finished", "success"):
        raise ScenarioFailed(f"(a) the 4-drone patrol ended {record['status']} ({record['cause']}): "
                             f"{record.get('message')}")
    simulated = (record["end"] - record["start"]) / 1000
    if simulated / wall < SPEEDUP_TARGET:
        raise ScenarioFailed(f"(a) the 4-drone patrol ran {simulated / wall:.0f}x real time, under the target of "
                             f"{SPEEDUP_TARGET}x ({simulated:.0f} s simulated in {wall:.2f} s wall)")
    samples = sum(len(d["samples"]) for d in result["drones"].values())
    print(f"(a) 4-drone patrol: {record['status']} ({record['cause']}), {simulated:.0f} s simulated "
          f"in {wall:.2f} s wall (field start included): {simulated / wall:.0f}x real time; {samples} telemetry samples")


async def verb_overhead(n: int) -> None:
    sent: list[float] = []
    received: list[float] = []
    original_build = script_mission.build_namespace
    original_on_command = Agent._on_command

    def build(mission: Any, guards: Any) -> dict[str, Any]:
        namespace = original_build(mission, guards)
        verb = namespace["arm"]

        def timed_arm(d: Any) -> None:
            sent.append(time.perf_counter())
            verb(d)

        namespace["arm"] = timed_arm
        return namespace

    async def on_command(self: Agent, key: str, payload: bytes) -> bytes:
        received.append(time.perf_counter())
        return await original_on_command(self, key, payload)

    script_mission.build_namespace = build
    Agent._on_command = on_command  # type: ignore[method-assign]
    field = SimField(World(), 1)
    try:
        await field.start()
        record = await field.run_mission(f"d = assign()\nfor _ in range({n}):\n    arm(d)\n", max_s=n * 3)
        assert record.status == "finished", record
    finally:
        await field.close()
        script_mission.build_namespace = original_build
        Agent._on_command = original_on_command  # type: ignore[method-assign]
    lat = sorted((r - s) * 1000 for s, r in zip(sent, received, strict=True))[20:]
    q = statistics.quantiles(lat, n=100)
    print(f"(b) verb → agent queryable, {len(lat)} `arm` calls: p50 {q[49]:.3f} ms, p99 {q[98]:.3f} ms "
          f"(+ Zenoh hop: see bench/ground_command.py)")


async def subroutines() -> None:
    for count in (200, 2000):
        field = SimField(World(), 1)
        await field.start()
        tracemalloc.start()
        before = tracemalloc.take_snapshot()
        t0 = time.perf_counter()
        assert field.manager is not None
        submitted = field.manager.submit(f"hs = [run(sleep, 5) for _ in range({count})]\nsleep(1)\n")
        await field.clock.advance(0.5)  # every subroutine started and sleeping
        started = time.perf_counter() - t0
        after = tracemalloc.take_snapshot()
        tracemalloc.stop()
        grown = sum(s.size_diff for s in after.compare_to(before, "filename"))
        record = await field.run_mission_started(submitted.mission_id, max_s=60)
        await field.close()
        assert record.status == "finished", record
        print(f"(c) {count} subroutines: {grown / count / 1024:.1f} KiB and {started / count * 1e6:.0f} µs each to start")


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--verbs", type=int, default=1000)
    args = parser.parse_args()
    await speedup()
    await verb_overhead(args.verbs)
    await subroutines()


if __name__ == "__main__":
    import logging

    logging.basicConfig(level=logging.ERROR)
    asyncio.run(main())
