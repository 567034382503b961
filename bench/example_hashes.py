"""The bytes every example writes: `fleet mission simulate` of each example script with
its world and a fixed seed, then the sha256 of its result.json (and how the mission
ended). Issue 33's check that a refactoring changed no behaviour: run it before and
after, the lines must be equal.

    python bench/example_hashes.py                    # this checkout
    python bench/example_hashes.py --module fleet     # a checkout from before the rename

Exits 1 if any run fails to write a result."""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
WORLDS = EXAMPLES / "worlds"
# Each example with the world its docstring names (or a drone count), at two seeds.
RUNS: list[tuple[str, list[str]]] = [
    ("mapping", ["--drones", "1"]),
    ("two_drones", ["--drones", "2"]),
    ("synchronisation", ["--drones", "2"]),
    ("mapping_with_replacement", ["--world", str(WORLDS / "mapping_with_replacement.yml")]),
    ("replacement_mapping", ["--world", str(WORLDS / "replacement.yml")]),
    ("fire_tracing", ["--world", str(WORLDS / "fire.yml")]),
    ("fire_tracing", ["--world", str(WORLDS / "fire_four_sources.yml")]),
    ("fire_patrol_bundle", ["--world", str(WORLDS / "fire.yml")]),
    ("survey_bundle", ["--world", str(WORLDS / "survey.yml")]),
    ("relay_mapping", ["--world", str(WORLDS / "relay.yml")]),
    ("relay_two_ways", ["--world", str(WORLDS / "relay_two_ways.yml")]),
    ("mapping", ["--world", str(WORLDS / "fenced.yml")]),
]
SEEDS = (1, 7)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--module", default="dronefleet", help="the package to run as `python -m MODULE`")
    args = parser.parse_args()
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i, (example, flags) in enumerate(RUNS):
            for seed in SEEDS:
                out = Path(tmp) / f"{i}-{seed}"
                done = subprocess.run(
                    [sys.executable, "-m", args.module, "mission", "simulate", str(EXAMPLES / f"{example}.py"), *flags,
                     "--seed", str(seed), "--out", str(out)],
                    capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL,
                )
                result = out / "result.json"
                world = Path(flags[-1]).name if flags[0] == "--world" else f"{flags[-1]} drones"
                if not result.exists():
                    failed += 1
                    print(f"{example:26} {world:30} seed {seed}: no result.json (exit {done.returncode}) "
                          f"{done.stderr.strip()[-300:]}")
                    continue
                data = result.read_bytes()
                status = json.loads(data).get("mission", {}).get("status", "?")
                print(f"{example:26} {world:30} seed {seed}: {hashlib.sha256(data).hexdigest()} {status}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
