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
from bus.port import Sample
from bus.zenoh_bus import ZenohBus
from schemas.keys import Keys
from tests.helpers import free_port

WARM_UP_S = 3.0  # imports, connecting, first heartbeats: not steady state


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
        async with asyncio.timeout(30):
            await first.wait()
        await asyncio.sleep(WARM_UP_S)
        count0 = len(received)
        window = Window(agent.pid)
        await asyncio.sleep(seconds)
        usage = window.stop()
        return (len(received) - count0) / usage.window_s, usage
    finally:
        agent.terminate()
        agent.wait(timeout=10)
        await client.close()
        await router.close()


def report(title: str, rate: float, usage: Usage) -> None:
    print(f"{title}, telemetry 100 ms, {usage.window_s:.1f} s window")
    print(f"  telemetry received : {rate:.2f} msg/s")
    print(f"  agent CPU          : {usage.cpu_percent:.2f} % of one core")
    print(f"  agent RSS          : {usage.rss_mib:.1f} MiB")
