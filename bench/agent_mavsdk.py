"""Agent with MAVSDK inside, against `fleet sim`: CPU and RSS at 10 Hz telemetry, and
the time from a command to its MAVSDK acknowledgement, for each simulated autopilot.

    .venv/bin/python bench/agent_mavsdk.py [--seconds 30] [--commands 200] [--autopilot px4,ardupilot]

(1) `fleet sim -n 1` and `fleet agent --fc udpin://…` run as child processes; the
agent's CPU share and RSS are read from /proc over the window. (2) In this process,
the MAVSDK adapter sends DO_CHANGE_SPEED (`set_current_speed`) N times to a second
simulated vehicle and times each call, which returns on the COMMAND_ACK.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.agent_window import measure_agent, report  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.agent.fc_mavsdk import MavsdkFlightController  # noqa: E402
from dronefleet.sim.mavlink_endpoint import MavlinkVehicle  # noqa: E402
from dronefleet.sim.vehicle import Vehicle  # noqa: E402
from tests.ports import free_udp_base


async def agent_usage(seconds: float, autopilot: str) -> None:
    base = free_udp_base(1)
    fleet = str(Path(sys.executable).with_name("fleet"))
    sim = subprocess.Popen([fleet, "sim", "-n", "1", "--base-port", str(base), "--autopilot", autopilot],
                           stdout=subprocess.DEVNULL)
    try:
        rate, usage = await measure_agent(f"udpin://127.0.0.1:{base}", seconds)
        if sim.poll() is not None:  # the agent would go on sending its last state
            raise ScenarioFailed(f"fleet sim exited ({sim.returncode}) during the window")
    finally:
        sim.terminate()
        sim.wait(timeout=10)
    report(f"agent --fc udpin (MAVSDK 4.1.0 in-process) against fleet sim --autopilot {autopilot}", rate, usage)


async def ack_latency(commands: int, autopilot: str) -> None:
    base = free_udp_base(1)
    endpoint = MavlinkVehicle(Vehicle(47.397742, 8.545594, 488.0), 1, [("127.0.0.1", base)], autopilot=autopilot)
    await endpoint.start(("127.0.0.1", 0))
    stepping = asyncio.get_running_loop().create_task(endpoint.run())
    fc = MavsdkFlightController(f"udpin://127.0.0.1:{base}")
    try:
        await fc.start()
        samples = []
        for i in range(commands):
            started = time.perf_counter()
            await fc.action.set_current_speed(3.0 + (i % 5))
            samples.append((time.perf_counter() - started) * 1000)
        samples.sort()
        p50 = statistics.median(samples)
        p99 = samples[min(len(samples) - 1, int(0.99 * len(samples)))]
        print(f"command -> MAVSDK acknowledgement ({autopilot}: DO_CHANGE_SPEED, {commands} commands, same host)")
        print(f"  p50 {p50:.2f} ms   p99 {p99:.2f} ms   max {samples[-1]:.2f} ms")
    finally:
        await fc.close()
        stepping.cancel()
        endpoint.close()


async def main(seconds: float, commands: int, autopilots: list[str]) -> None:
    for autopilot in autopilots:
        await agent_usage(seconds, autopilot)
        await ack_latency(commands, autopilot)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--commands", type=int, default=200)
    parser.add_argument("--autopilot", default="px4,ardupilot", help="simulated autopilots, in turn")
    args = parser.parse_args()
    asyncio.run(main(args.seconds, args.commands, [a for a in args.autopilot.split(",") if a]))
