"""Does link quality warn before the link is gone? (issue 57, ADR 0003 "Link quality")

A drone is flown straight out of the laptop's range at `--speed` m/s, on real packets:
the real `fleet ground`, `fleet sim WORLD --agents --radio` (the emulated radio, one
namespace per node), `fleet sub` on board recording what the agent reported. For each
fly-out: how long its quality to the ground had stayed under 0.5 when the ground lost
it, and where it first fell under 0.5; then the same world in fast time, for
comparison. Needs CAP_NET_ADMIN (root).

    .venv/bin/python bench/link_flyout.py [--runs 20] [--radios 40/70,60/100] [--speed 5]

Prints one line per fly-out and a summary per radio; exits 1 if any fly-out warned for
less than 3 s before the ground lost the drone (the bar of issue 57: 20 of 20).
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
from dronefleet.sim.radio import RadioModel  # noqa: E402
from dronefleet.sim.radio_net import has_net_admin  # noqa: E402
from tests.flyout import fast_flyout, real_flyout  # noqa: E402

BAR_S = 3.0


async def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="fly-outs per radio on real packets")
    parser.add_argument("--radios", default="40/70,60/100", help="GOOD/LOST in metres, comma-separated")
    parser.add_argument("--speed", type=float, default=5.0, help="m/s out (the cruise speed is 5)")
    args = parser.parse_args()
    if not has_net_admin():
        raise ScenarioFailed("the emulated radio needs CAP_NET_ADMIN (run as root)")
    short = 0
    for text in args.radios.split(","):
        good, lost = (float(x) for x in text.split("/"))
        radio = RadioModel(good_m=good, lost_m=lost)
        warned: list[float] = []
        where: list[float] = []
        for run in range(args.runs):
            with tempfile.TemporaryDirectory(prefix="link-flyout-") as tmp:
                f = await real_flyout(Path(tmp), radio, args.speed)
            w, at = f.degraded_s(), f.first_degraded_m()
            warned.append(w if w is not None else 0.0)
            where.append(at if at is not None else float("nan"))
            lost_m = f.track[-1][1] if f.track else float("nan")
            print(f"radio {text} m, fly-out {run + 1}: quality under 0.5 from {where[-1]:.1f} m, "
                  f"{warned[-1]:.1f} s before the ground lost the drone (at about {lost_m:.0f} m)", flush=True)
        fast = [await fast_flyout(radio, args.speed, seed) for seed in range(args.runs)]
        fast_where = [f.first_degraded_m() or float("nan") for f in fast]
        ok = sum(w >= BAR_S for w in warned)
        short += len(warned) - ok
        print(f"radio {text} m at {args.speed:g} m/s: warned >= {BAR_S:g} s before the loss in {ok} of {len(warned)} "
              f"real fly-outs (warning p50 {statistics.median(warned):.1f} s, least {min(warned):.1f} s); "
              f"quality first under 0.5 at {statistics.median(where):.1f} m median on real packets, "
              f"{statistics.median(fast_where):.1f} m in fast time ({len(fast)} seeds)", flush=True)
    return 1 if short else 0


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
