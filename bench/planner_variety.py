"""Random plans through the dashboard's planner, judged by rates (issue 34).

Starts a real `fleet ground` with sim agents and headless Chromium, then for each seed
puts a random plan into the page's planner (1-3 drones, 1-6 waypoints each within
80 m of the drone, altitude 5-30 m, speed 2-12 m/s, hold 0-3 s, ending with land,
return or hold), takes the script the page generates and its checks, and asks the
ground to simulate it (`POST /mission/simulate`). Prints how many plans the page
refused (targets closer than the separation, each also found here), how many
predicted flights finished, how many passed every waypoint within 2 m at its altitude
and ended as planned, and the simulation's wall time.

    .venv/bin/python bench/planner_variety.py [--plans 40] [--seed 0]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.dashboard_frames import DESKTOP, launch_chromium  # noqa: E402
from dronefleet.schemas.geo import destination, distance_m  # noqa: E402
from tests.harness import GroundFleet  # noqa: E402

HOME = (40.633400, -8.660810)
SPAWNS = {f"drone0{i + 1}": destination(*HOME, 12 * i, 90) for i in range(3)}
SEPARATION_M = 5.0


def random_plan(rng: random.Random) -> tuple[dict[str, list[dict[str, float]]], float, str]:
    plans = {}
    for drone in rng.sample(sorted(SPAWNS), rng.randint(1, 3)):
        points = []
        for _ in range(rng.randint(1, 6)):
            lat, lon = destination(*SPAWNS[drone], rng.uniform(5, 80), rng.uniform(0, 360))
            points.append({"lat": lat, "lon": lon, "alt": float(rng.randint(5, 30)), "speed": float(rng.randint(2, 12)),
                           "hold_s": float(rng.choice([0, 0, 1, 3]))})
        plans[drone] = points
    return plans, float(rng.randint(5, 20)), rng.choice(["land", "return", "hold"])


def conflicts(plans: dict[str, list[dict[str, float]]]) -> bool:
    flat = [(d, p) for d, points in plans.items() for p in points]
    return any(a[0] != b[0] and math.hypot(distance_m(a[1]["lat"], a[1]["lon"], b[1]["lat"], b[1]["lon"]),
                                           a[1]["alt"] - b[1]["alt"]) < SEPARATION_M
               for i, a in enumerate(flat) for b in flat[i + 1:])


def judge(plans: dict[str, list[dict[str, float]]], end: str, predicted: dict[str, Any]) -> str | None:
    """None when the predicted flight did what the plan says, else why not."""
    if (predicted["status"], predicted["cause"]) != ("finished", "success"):
        return f"{predicted['status']} {predicted['cause']}: {predicted['message']}"
    for drone, points in plans.items():
        path = predicted["drones"].get(drone, {}).get("path") or []
        if not path:
            return f"{drone}: no predicted path"
        for n, p in enumerate(points):
            # nearest in 3-D: a drone may reach the spot before the altitude (a steep leg)
            best = min(path, key=lambda s: math.hypot(distance_m(s[1], s[2], p["lat"], p["lon"]), s[3] - p["alt"]))
            if distance_m(best[1], best[2], p["lat"], p["lon"]) > 2.0 or abs(best[3] - p["alt"]) > 1.5:
                return f"{drone} waypoint {n + 1}: nearest {distance_m(best[1], best[2], p['lat'], p['lon']):.1f} m, alt {best[3]:.1f}"
        last = path[-1]
        if end in ("land", "return") and last[3] > 0.5:
            return f"{drone} ended {last[3]:.1f} m up after {end}"
        if end == "return" and distance_m(last[1], last[2], *SPAWNS[drone]) > 2.0:
            return f"{drone} ended {distance_m(last[1], last[2], *SPAWNS[drone]):.1f} m from home"
        if end == "hold" and last[3] < 3.0:
            return f"{drone} ended on the ground after hold"
    return None


async def run(count: int, seed: int) -> int:
    from playwright.async_api import async_playwright  # noqa: F401  (installed with the test extras)

    from tests.dashboard.page import chromium

    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix="planner-variety-"))
    fcs = {d: f"sim://?lat={lat}&lon={lon}&alt=8.2" for d, (lat, lon) in SPAWNS.items()}
    fleet = GroundFleet(tmp, fcs, {"telemetry_rate_ms": 200, "max_speed": 12})
    refused = finished = good = 0
    walls: list[float] = []
    failures: list[str] = []
    try:
        async with fleet.client() as http, launch_chromium(chromium()) as browser:
            page = await (await browser.new_context(viewport=DESKTOP)).new_page()
            await page.goto(fleet.ground.url)
            await page.wait_for_function("() => window.fleetDashboard?.fleet.drones.size === 3", timeout=30_000)
            for i in range(count):
                plans, takeoff, end = random_plan(rng)
                await page.evaluate("""([plans, takeoff, end]) => {
                    const p = window.fleetDashboard.planner;
                    document.getElementById('plan-takeoff').value = takeoff;
                    document.getElementById('plan-end').value = end;
                    p.plans = new Map(Object.entries(plans));
                    p.changed();
                }""", [plans, takeoff, end])
                problems = await page.evaluate("() => window.fleetDashboard.planner.check()")
                local = [p for p in problems if "targets conflict" in p["text"]]
                if conflicts(plans) != bool(local):
                    failures.append(f"plan {i}: the page's conflict check disagrees ({local})")
                if problems:
                    refused += 1
                    continue
                source = await page.evaluate("() => document.getElementById('plan-script').value")
                started = time.monotonic()
                r = await http.post("/mission/simulate", json={"source": source}, timeout=300)
                walls.append(time.monotonic() - started)
                if r.status_code != 200:
                    failures.append(f"plan {i}: {r.status_code} {r.text[:200]}")
                    continue
                predicted = r.json()
                finished += predicted["status"] == "finished"
                why = judge(plans, end, predicted)
                if why is None:
                    good += 1
                else:
                    failures.append(f"plan {i} ({end}, {sum(len(p) for p in plans.values())} waypoints): {why}")
                print(f"plan {i + 1}/{count}: {'refused' if problems else predicted['status']}"
                      f"{'' if why is None else ' — ' + why}", flush=True)
    finally:
        fleet.stop()
    simulated = count - refused
    print(f"\n{count} random plans (seed {seed}): {refused} refused by the page's checks (targets closer than "
          f"{SEPARATION_M:g} m), {simulated} simulated")
    if simulated:
        print(f"finished: {finished}/{simulated} ({100 * finished / simulated:.0f} %); flew as planned (every waypoint "
              f"within 2 m at its altitude, ended as planned): {good}/{simulated} ({100 * good / simulated:.0f} %)")
        print(f"simulate wall time: p50 {statistics.median(walls):.2f} s, max {max(walls):.2f} s")
    for line in failures:
        print("  " + line)
    return 0 if good == simulated and not any("disagrees" in f for f in failures) else 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plans", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    sys.exit(asyncio.run(run(args.plans, args.seed)))


if __name__ == "__main__":
    main()
