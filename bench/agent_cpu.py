"""Agent CPU share of one core and RSS at 10 Hz telemetry, `--fc sim`.

    .venv/bin/python bench/agent_cpu.py [--seconds 30]

Starts a Zenoh router in this process and `fleet agent --fc sim` as a child,
subscribes to its telemetry, then measures the agent process over a window.
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.procstat import Window  # noqa: E402
from bus.port import Sample  # noqa: E402
from bus.zenoh_bus import ZenohBus  # noqa: E402
from schemas.keys import Keys  # noqa: E402
from tests.helpers import free_port  # noqa: E402


async def main(seconds: float) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = await ZenohBus.open("router", listen=[endpoint])
    fleet = Path(sys.executable).with_name("fleet")
    agent = subprocess.Popen(
        [str(fleet), "agent", "--id", "bench01", "--fc", "sim", "--connect", endpoint, "--telemetry-rate-ms", "100"],
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
        await asyncio.sleep(2)  # start-up (imports, connect) is not steady state
        count0 = len(received)
        window = Window(agent.pid)
        await asyncio.sleep(seconds)
        usage = window.stop()
        rate = (len(received) - count0) / usage.window_s
        print(f"agent --fc sim, telemetry 100 ms, {usage.window_s:.1f} s window")
        print(f"  telemetry received : {rate:.2f} msg/s")
        print(f"  agent CPU          : {usage.cpu_percent:.2f} % of one core")
        print(f"  agent RSS          : {usage.rss_mib:.1f} MiB")
    finally:
        agent.terminate()
        agent.wait(timeout=10)
        await client.close()
        await router.close()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    asyncio.run(main(parser.parse_args().seconds))
