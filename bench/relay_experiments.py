"""The relay experiments of issue 15 (fleet/relay_experiments.py): the table in the
README, and each run's result.json and plots.

    .venv/bin/python bench/relay_experiments.py [--out out/relay-experiments] [--seed 0]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet import relay_experiments as rx  # noqa: E402


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/relay-experiments"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = []
    for key, experiment in rx.ALL.items():
        out = args.out / key
        out.mkdir(parents=True, exist_ok=True)
        print(f"running {experiment.name} …", file=sys.stderr, flush=True)
        result = await rx.run(experiment, out, seed=args.seed)
        # The control is out of reach for good without relays; with them, the mission must finish.
        expected = ("finished", "success") if experiment.relay is not None else ("failed", "link_lost")
        record = result["mission"]
        if (record["status"], record["cause"]) != expected:
            raise ScenarioFailed(f"{experiment.name}: the mission ended {record['status']} ({record['cause']}), "
                                 f"not {expected[0]} ({expected[1]}): {record.get('message')}")
        rows.append((experiment.name, rx.metrics(result, experiment.served)))
    print(rx.table(rows))
    print(f"\nresults and plots in {args.out}/<experiment>/", file=sys.stderr)


if __name__ == "__main__":
    asyncio.run(main())
