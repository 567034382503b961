"""What each way of joining the mesh costs a drone process (ADR 0003): RSS and CPU of
a process that opens one Zenoh session as client, peer or router (the agent's options),
connects to a ground router and publishes a telemetry-sized sample at 10 Hz.

    .venv/bin/python bench/zenoh_modes.py [--seconds 20]

The difference to `client` is what the option adds to the agent; `bench/agent_cpu.py`
gives the whole agent (a router with its link probes).
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.procstat import Usage, Window  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from tests.ports import free_port

WARM_UP_S = 3.0

CHILD = """
import asyncio, sys
from dronefleet.bus.zenoh_bus import ZenohBus

async def main(mode, connect, listen):
    bus = await ZenohBus.open(mode, connect=[connect], listen=[listen] if listen else [])
    payload = b"x" * 420  # a Telemetry message as JSON
    print("open", flush=True)
    while True:
        bus.publish("drone/bench01/telem", payload)
        await asyncio.sleep(0.1)

asyncio.run(main(sys.argv[1], sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else None))
"""


async def measure(mode: str, seconds: float) -> Usage:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ground = await ZenohBus.open("router", listen=[endpoint])
    args = [sys.executable, "-c", CHILD, mode, endpoint]
    if mode == "router":
        args.append(f"tcp/127.0.0.1:{free_port()}")
    child = subprocess.Popen(args, stdout=subprocess.PIPE, cwd=Path(__file__).resolve().parents[1])
    try:
        assert child.stdout is not None
        try:
            line = await asyncio.wait_for(asyncio.to_thread(child.stdout.readline), 30)
        except TimeoutError:
            line = b""
        if line.strip() != b"open":
            raise ScenarioFailed(f"the {mode} session did not open within 30 s")
        await asyncio.sleep(WARM_UP_S)
        window = Window(child.pid)
        await asyncio.sleep(seconds)
        if child.poll() is not None:  # a dead session's CPU and RSS are no session's
            raise ScenarioFailed(f"the {mode} session's process exited ({child.returncode}) during the window")
        return window.stop()
    finally:
        child.terminate()
        child.wait(timeout=10)
        await ground.close()


async def main(seconds: float) -> None:
    print(f"one Zenoh session publishing 10 Hz to a ground router, {seconds:g} s window")
    base: Usage | None = None
    for mode in ("client", "peer", "router"):
        usage = await measure(mode, seconds)
        base = base or usage
        print(f"  {mode:<7}: CPU {usage.cpu_percent:5.2f} % of one core, RSS {usage.rss_mib:5.1f} MiB "
              f"({usage.rss_mib - base.rss_mib:+.1f} MiB, {usage.cpu_percent - base.cpu_percent:+.2f} % vs client)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    asyncio.run(main(parser.parse_args().seconds))
