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

With `--fly`, each example the prediction finished then flies for real on the same
fleet (no preflight: it was just predicted), and the prediction is compared with the
flight: duration, and each drone's least battery; exits 1 when a duration is off by
more than `--error-bar` (10 %). The drones come home between examples.

`--autopilot px4` flies the four drones on real PX4 SITL instead (the SIH quad, four
instances standing where the simulated ones would, from $FLEET_PX4_BUILD; see
docs/guides/real-hardware.md), through `fleet agent --fc udpin://…` as on a real drone.
SIH's battery is no pack (it falls to 50 % in a minute and stays): predictions drain none,
and the battery is not compared:

    FLEET_PX4_BUILD=~/PX4-Autopilot/build/px4_sitl_default .venv/bin/python bench/preflight.py --fly --autopilot px4
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.autopilot_contract import Px4Sitl, px4_build  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.agent.config import AgentConfig  # noqa: E402
from dronefleet.sim.vehicle import VehicleParams  # noqa: E402
from tests.harness import GroundFleet, SimProcess  # noqa: E402
from tests.waiting import until

EXAMPLES = sorted(p for p in (Path(__file__).resolve().parents[1] / "examples").glob("*.py") if p.name != "__init__.py")
FLOWN_S = 10.0  # a mission refused at its start has no length to compare with
VEHICLE_DRAIN_PER_S = VehicleParams().battery_drain_per_s  # what the simulated vehicles drain


@dataclass
class Flown:
    duration_s: float
    battery_left: dict[str, float]  # the least each drone held while the mission ran


async def fly(http: httpx.AsyncClient, source: str, name: str, drones: list[str]) -> Flown:
    """Fly `source` for real (no preflight: its prediction was just made), watching each
    drone's battery; then wait until every drone is back, disarmed, on the ground."""
    response = await http.post("/mission", content=source.encode(), params={"name": name, "preflight": "false"})
    if response.status_code != 201:
        raise ScenarioFailed(f"{name}: submit {response.status_code} {response.text}")
    mission_id = response.json()["mission_id"]
    least: dict[str, float] = {}
    while True:
        record = (await http.get(f"/mission/{mission_id}")).json()
        for drone in drones:
            telem = (await http.get(f"/drone/{drone}", params={"data": "telem"})).json().get("telem") or {}
            battery = (telem.get("battery") or {}).get("remaining_percent")
            if battery is not None:
                least[drone] = min(least.get(drone, 1.0), battery)
        if record["end"] is not None:
            break
        await asyncio.sleep(1.0)  # a sample a second: the battery's resolution here
    await until(lambda: all_ready(http, len(drones)), 300, f"every drone back after {name}")
    if os.environ.get("FLEET_BENCH_LOG"):  # the flight's own account, to find where time went
        for line in record.get("log") or []:
            print(f"    {(line['timestamp'] - record['start']) / 1000:7.1f} s  {line['message']}")
        used = record.get("used_drones") or drones
        lines = (await http.get("/drone/logs", params={"drone_id": used})).text.splitlines()
        print("\n".join(line for line in lines if " Start " in line or " Finish " in line or "mission" in line))
    used = record.get("used_drones") or []
    return Flown(duration_s=(record["end"] - record["start"]) / 1000, battery_left={d: least[d] for d in used if d in least})


async def all_ready(http: httpx.AsyncClient, n: int) -> bool:
    views = (await http.get("/drone")).json()
    return sum(v["info"]["state"] == "ready" for v in views) == n


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bar", type=float, default=0.05, help="largest wall / simulated ratio allowed")
    parser.add_argument("--fly", action="store_true",
                        help="also fly each example that the prediction finished, and compare (duration, battery)")
    parser.add_argument("--error-bar", type=float, default=0.10, help="with --fly: largest duration error allowed")
    parser.add_argument("--autopilot", choices=["sim", "sim-px4", "px4"], default="sim",
                        help="the drones' flight controllers: the agents' built-in simulator, `fleet sim` as PX4 "
                             "(MAVLink through MAVSDK), or real PX4 SITL ($FLEET_PX4_BUILD)")
    parser.add_argument("--only", metavar="NAME", action="append", help="only this example (file stem; repeatable)")
    parser.add_argument("--first-instance", type=int, default=0,
                        help="with --autopilot px4: the first SITL instance (PX4 -i), to fly beside another SITL")
    args = parser.parse_args()
    errors: list[float] = []
    examples = [p for p in EXAMPLES if not args.only or p.stem in args.only]
    spots = [(40.6334, -8.66081 + 0.00013 * i, 8.2) for i in range(4)]
    sitls: list[Px4Sitl | SimProcess] = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.autopilot == "sim-px4":  # its default world: a row of drones east of the origin
            sim = SimProcess(Path(tmp), n=len(spots), extra_args=["--autopilot", "px4"])
            sitls.append(sim)
            fcs = {f"drone{i + 1:02d}": sim.fc_url(i) for i in range(len(spots))}
        elif args.autopilot == "px4":
            build = px4_build("bench/preflight.py --autopilot px4")
            quads = [Px4Sitl(build, args.first_instance + i, home=spot) for i, spot in enumerate(spots)]
            for i, quad in enumerate(quads):
                sitls.append(quad)
                (Path(tmp) / f"px4-{i}").mkdir()
                quad.start(Path(tmp) / f"px4-{i}")
            fcs = {f"drone{i + 1:02d}": quad.fc_url for i, quad in enumerate(quads)}
            print(f"flying on {len(quads)} x {quads[0].name.rsplit(' -i', 1)[0]}", flush=True)
        else:
            fcs = {f"drone{i + 1:02d}": f"sim://?lat={lat}&lon={lon:.6f}&alt={alt}" for i, (lat, lon, alt) in enumerate(spots)}
        # PX4's SIH holds its battery at 50 % after the first minute: no pack to predict, so
        # the prediction drains none either (a replacement would fly in one and not the other)
        drain_per_s = 0.0 if args.autopilot == "px4" else VEHICLE_DRAIN_PER_S
        # The agents at their default telemetry rate (as the prediction's are), the prediction
        # draining batteries as the simulated vehicles do, drones home at a mission's end.
        fleet = GroundFleet(Path(tmp), fcs, {"telemetry_rate_ms": AgentConfig().telemetry_rate_ms},
                            mission={"preflight": True, "flight_drain_per_s": drain_per_s, "end_action": "return"})
        try:
            async with fleet.client() as http:
                await until(lambda: all_ready(http, len(fcs)), 60, "four drones ready")
                walls, ratios = [], []
                for path in examples:
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
                    if args.fly and p["status"] == "finished":
                        flown = await fly(http, path.read_text(), path.stem, list(fcs))
                        error = (p["duration_s"] - flown.duration_s) / flown.duration_s
                        errors.append(error)
                        batteries = ", ".join(
                            f"{d} {p['drones'][d]['battery_end']:.0%}/{flown.battery_left[d]:.0%}"
                            for d in sorted(flown.battery_left) if d in p["drones"] and p["drones"][d]["battery_end"] is not None)
                        print(f"{'':32} flown {flown.duration_s:7.1f} s: duration error {error:+.1%}; "
                              f"battery left predicted/flown {batteries or 'n/a'}", flush=True)
        finally:
            fleet.stop()
            for sitl in sitls:
                sitl.stop()
    print(f"preflight wall time over {len(walls)} examples: p50 {statistics.median(walls):.2f} s, max {max(walls):.2f} s; "
          f"wall / simulated over the {len(ratios)} that flew: p50 {statistics.median(ratios):.2%}, "
          f"max {max(ratios):.2%} (bar {args.bar:.0%})")
    if errors:
        worst = max(errors, key=abs)
        print(f"prediction against flight over {len(errors)} examples: duration error p50 "
              f"{statistics.median(map(abs, errors)):.1%}, worst {worst:+.1%} (bar {args.error_bar:.0%})")
    if max(ratios) > args.bar or any(abs(e) > args.error_bar for e in errors):
        raise SystemExit(1)


if __name__ == "__main__":
    asyncio.run(main())
