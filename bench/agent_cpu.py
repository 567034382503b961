"""Agent CPU share of one core and RSS at 10 Hz telemetry, `--fc sim`.

    .venv/bin/python bench/agent_cpu.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.agent_window import measure_agent, report  # noqa: E402


async def main(seconds: float) -> None:
    rate, usage = await measure_agent("sim", seconds)
    report("agent --fc sim", rate, usage)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    asyncio.run(main(parser.parse_args().seconds))
