"""Measure one `fleet agent` process: telemetry it delivers, CPU share, RSS.

Shared by the agent benchmarks: a Zenoh router in this process, the agent as a
child with 100 ms telemetry, a subscriber counting what arrives, /proc readings.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path

from bench.procstat import Usage, Window
from bench.verdict import ScenarioFailed
from dronefleet.bus.port import Sample
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.keys import Keys
from tests.ports import free_port

WARM_UP_S = 3.0  # imports, connecting, first heartbeats: not steady state
TELEMETRY_HZ = 10.0  # --telemetry-rate-ms 100


async def measure_agent(fc_url: str, seconds: float) -> tuple[float, Usage]:
    """(telemetry msg/s received, agent usage) over a window of `seconds`."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = await ZenohBus.open("router", listen=[endpoint])
    fleet = str(Path(sys.executable).with_name("fleet"))
    agent = subprocess.Popen(
        [fleet, "agent", "--id", "bench01", "--fc", fc_url, "--connect", endpoint, "--telemetry-rate-ms", "100"],
        stderr=subprocess.DEVNULL,
    )
    client = await ZenohBus.open("client", connect=[endpoint])
    received: list[float] = []
    first = asyncio.Event()

    def on_telem(_: Sample) -> None:
        received.append(time.monotonic())
        first.set()

    try:
        client.subscribe(Keys().telem("bench01"), on_telem)
        try:
            async with asyncio.timeout(30):
                await first.wait()
        except TimeoutError:
            died = "" if agent.poll() is None else f"; it exited ({agent.returncode})"
            raise ScenarioFailed(f"no telemetry from the agent within 30 s{died}") from None
        await asyncio.sleep(WARM_UP_S)
        count0 = len(received)
        window = Window(agent.pid)
        await asyncio.sleep(seconds)
        if agent.poll() is not None:  # a dead agent's CPU and RSS are no agent's
            raise ScenarioFailed(f"the agent exited ({agent.returncode}) during the window")
        usage = window.stop()
        got = len(received) - count0
        rate = got / usage.window_s
        # The agent stalled or lost its FC: not the steady state measured (a window's edges may cut one sample).
        if got < 0.9 * TELEMETRY_HZ * usage.window_s - 1:
            raise ScenarioFailed(f"{rate:.2f} telemetry msg/s at the ground, under 90 % of the agent's {TELEMETRY_HZ:g} Hz")
        return rate, usage
    finally:
        agent.terminate()
        agent.wait(timeout=10)
        await client.close()
        await router.close()


# An agent at rest on the ground (issue 80): at most this much of a core and memory.
CPU_BAR_PERCENT = 2.0
RSS_BAR_MIB = 50.0


def report(title: str, rate: float, usage: Usage, rss_bar_mib: float | None = RSS_BAR_MIB) -> None:
    """Print the figures; exit 1 (after printing) over the CPU bar, or over `rss_bar_mib`."""
    print(f"{title}, telemetry 100 ms, {usage.window_s:.1f} s window")
    print(f"  telemetry received : {rate:.2f} msg/s")
    print(f"  agent CPU          : {usage.cpu_percent:.2f} % of one core (bar {CPU_BAR_PERCENT:g} %)")
    print(f"  agent RSS          : {usage.rss_mib:.1f} MiB" + (f" (bar {rss_bar_mib:g} MiB)" if rss_bar_mib else ""))
    if usage.cpu_percent > CPU_BAR_PERCENT:
        raise ScenarioFailed(f"the agent at rest took {usage.cpu_percent:.2f} % of a core, over {CPU_BAR_PERCENT:g} %")
    if rss_bar_mib is not None and usage.rss_mib > rss_bar_mib:
        raise ScenarioFailed(f"the agent at rest held {usage.rss_mib:.1f} MiB, over {rss_bar_mib:g} MiB")
