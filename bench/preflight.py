"""What a submission's preflight costs (issue 59): for every example, the wall time of its
fast-time run against the live fleet, beside the mission's own simulated length.

    .venv/bin/python bench/preflight.py [--bar 0.05]

`fleet ground` and four `fleet agent --fc sim` children on loopback (no sensors, no
radio: the examples that need them are refused, as they would be on this fleet); each
example is flown by the ground's own prediction (POST /mission/simulate: the same child
process, live world and bound, `mission.preflight_max_s`, as a submission's preflight —
ground/preflight.py) so nothing flies. Prints p50 and max of the wall time, and of its
ratio to the simulated length for the missions that flew 10 s or more; exits 1 when the
largest ratio is over `--bar`.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.verdict import ScenarioFailed  # noqa: E402
from tests.harness import GroundFleet  # noqa: E402
from tests.waiting import until

EXAMPLES = sorted(p for p in (Path(__file__).resolve().parents[1] / "examples").glob("*.py") if p.name != "__init__.py")
FLOWN_S = 10.0  # a mission refused at its start has no length to compare with


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bar", type=float, default=0.05, help="largest wall / simulated ratio allowed")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        fcs = {f"drone{i + 1:02d}": f"sim://?lat=40.6334&lon={-8.66081 + 0.00013 * i:.6f}&alt=8.2" for i in range(4)}
        fleet = GroundFleet(Path(tmp), fcs, {"telemetry_rate_ms": 200}, mission={"preflight": True})
        try:
            async with fleet.client() as http:
                async def ready() -> bool:
                    views = (await http.get("/drone")).json()
                    return sum(v["info"]["state"] == "ready" for v in views) == len(fcs)

                await until(ready, 60, "four drones ready")
                walls, ratios = [], []
                for path in EXAMPLES:
                    response = await http.post("/mission/simulate", json={"source": path.read_text()}, timeout=300)
                    if response.status_code != 200:
                        raise ScenarioFailed(f"{path.name}: {response.status_code} {response.text}")
                    p = response.json()
                    walls.append(p["wall_s"])
                    ratio = p["wall_s"] / p["duration_s"] if p["duration_s"] >= FLOWN_S else None
                    if ratio is not None:
                        ratios.append(ratio)
                    print(f"{path.name:32} {p['status']:9} {p['cause'] or '':12} {p['duration_s']:7.1f} s simulated "
                          f"in {p['wall_s']:5.2f} s" + (f" ({ratio:.2%})" if ratio is not None else ""), flush=True)
        finally:
            fleet.stop()
    print(f"preflight wall time over {len(walls)} examples: p50 {statistics.median(walls):.2f} s, max {max(walls):.2f} s; "
          f"wall / simulated over the {len(ratios)} that flew: p50 {statistics.median(ratios):.2%}, "
          f"max {max(ratios):.2%} (bar {args.bar:.0%})")
    if max(ratios) > args.bar:
        raise SystemExit(1)


if __name__ == "__main__":
    asyncio.run(main())
