"""The relay experiments of issue 15 in fast time, judged from result.json.

- **Mapping** (thesis script 6.2, `examples/relay_mapping.py` on `worlds/relay.yml`):
  the same mission with no relay plugin, with the thesis's distance mode and with the
  measured mode.
- **Two ways** (`examples/relay_two_ways.py` on `worlds/relay_two_ways.yml`): two
  drones working 60° apart, distance mode (one chain per drone) against measured mode.

`metrics()` reads one result: the longest gap in each served drone's telemetry at the
ground, the share of the mission during which it was heard at least every 2.5 s, the relays that
flew, the battery spent by the whole fleet, and the least 3-D distance between an
airborne relay and another relay or a served drone (on the flown paths, sampled each
second). `python -m bench.relay_experiments` prints the table and writes the plots.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dronefleet import examples
from dronefleet.compose import simulate
from dronefleet.relay.ways import Point3, closest_approach
from dronefleet.sim.projection import LocalFrame
from dronefleet.sim.world import load_world

EXAMPLES = examples.DIR
CONNECTED_GAP_S = 2.5
AIRBORNE_M = 1.0  # above home: flying, for the separation check
GROUND = "ground=[40.634125, -8.660336]"


@dataclass(frozen=True)
class Experiment:
    name: str
    script: str  # file in examples/
    world: str  # file in examples/worlds/
    served: tuple[str, ...]  # the mission's own drones (not relays)
    relay: str | None  # the enable("relay", …) line, None for no relay
    max_s: float = 900.0

    def source(self) -> str:
        text = (EXAMPLES / self.script).read_text()
        line = next(line for line in text.splitlines() if line.startswith('enable("relay"'))
        return text.replace(line, self.relay if self.relay is not None else "# no relay plugin")


MAPPING = {
    "none": Experiment("mapping, no relay", "relay_mapping.py", "relay.yml", ("drone01",), None),
    "distance": Experiment("mapping, distance mode", "relay_mapping.py", "relay.yml", ("drone01",),
                           f'enable("relay", mode="distance", target_dist=50 * m, base_alt=5 * m, alt_diff=5 * m, {GROUND})'),
    "measured": Experiment("mapping, measured mode", "relay_mapping.py", "relay.yml", ("drone01",),
                           f'enable("relay", mode="measured", min_quality=0.6, step=4 * m, base_alt=5 * m, alt_diff=5 * m, {GROUND})'),
}
TWO_WAYS = {
    "distance": Experiment("two ways, distance mode", "relay_two_ways.py", "relay_two_ways.yml", ("drone01", "drone02"),
                           f'enable("relay", mode="distance", target_dist=50 * m, {GROUND})', max_s=400.0),
    "measured": Experiment("two ways, measured mode", "relay_two_ways.py", "relay_two_ways.yml", ("drone01", "drone02"),
                           f'enable("relay", mode="measured", {GROUND})', max_s=400.0),
}
ALL = {**{f"mapping-{k}": v for k, v in MAPPING.items()}, **{f"two-ways-{k}": v for k, v in TWO_WAYS.items()}}


async def run(experiment: Experiment, out_dir: Path | None = None, seed: int = 0) -> dict[str, Any]:
    world = load_world(EXAMPLES / "worlds" / experiment.world)
    return await simulate(experiment.source(), world, seed=seed, out_dir=out_dir, name=experiment.script,
                          max_s=experiment.max_s, plots=out_dir is not None)


@dataclass(frozen=True)
class Metrics:
    status: str  # the mission's status and cause
    longest_gap_s: float  # over the served drones
    connected: float  # share of the mission heard at least every CONNECTED_GAP_S, the worst served drone
    relays: int  # drones other than the served ones that flew
    battery: float  # spent by the whole fleet, in battery fractions (1.0 = one full battery)
    separation_m: float  # the least distance of an airborne relay to another relay or a served drone (inf: none flew)


def span_s(result: dict[str, Any]) -> tuple[float, float]:
    record = result["mission"]
    return (record["start"] - result["t0_ms"]) / 1000, (record["end"] - result["t0_ms"]) / 1000


def heard(result: dict[str, Any], drone_id: str) -> list[float]:
    start, end = span_s(result)
    return [s["t_s"] for s in result["drones"][drone_id]["samples"] if start <= s["t_s"] <= end]


def longest_gap(result: dict[str, Any], drone_id: str) -> float:
    start, end = span_s(result)
    times = [start, *heard(result, drone_id), end]
    return max(b - a for a, b in itertools.pairwise(times))


def connected_share(result: dict[str, Any], drone_id: str) -> float:
    """The share of the mission during which the ground heard the drone at least every
    CONNECTED_GAP_S (one telemetry message lost at 1 Hz still counts as connected)."""
    start, end = span_s(result)
    times = [start, *heard(result, drone_id), end]
    return sum(b - a for a, b in itertools.pairwise(times) if b - a <= CONNECTED_GAP_S) / max(end - start, 1e-9)


def track(result: dict[str, Any], drone_id: str) -> list[dict[str, Any]]:
    drone = result["drones"][drone_id]
    return drone.get("flown") or drone["samples"]


def relays_flown(result: dict[str, Any], served: tuple[str, ...]) -> list[str]:
    return sorted(d for d in result["drones"] if d not in served and any(p["rel_alt"] > AIRBORNE_M for p in track(result, d)))


def battery_spent(result: dict[str, Any]) -> float:
    spent = 0.0
    for drone in result["drones"].values():
        levels = [s["battery"] for s in drone["samples"] if s["battery"] is not None]
        if levels:
            spent += levels[0] - min(levels)
    return spent


def least_separation(result: dict[str, Any], served: tuple[str, ...]) -> float:
    """The least 3-D distance between an airborne relay and another relay or a served drone."""
    relays = relays_flown(result, served)
    pairs = [(relay, other) for relay in relays for other in [*relays, *served]
             if not (other <= relay and other in relays)]  # each pair of relays once
    return least_distance(result, pairs)


def least_distance(result: dict[str, Any], pairs: Iterable[tuple[str, str]]) -> float:
    """The least 3-D distance between the two drones of any of `pairs` while both were
    airborne, in continuous time (issue 78): between two moments both tracks hold, each
    drone flew straight at constant speed, and the closest approach of the two over
    that interval counts (relay/ways.py `closest_approach`), not only the distance at
    its ends. An interval counts when both were airborne at one of its ends at least.
    inf: never both airborne."""
    frame: LocalFrame | None = None
    tracks: dict[str, dict[float, tuple[Point3, bool]]] = {}
    for d in result["drones"]:
        points: dict[float, tuple[Point3, bool]] = {}
        for p in track(result, d):
            frame = frame or LocalFrame(p["lat"], p["lon"])
            north, east = frame.to_local(p["lat"], p["lon"])
            points[p["t_s"]] = ((north, east, p["rel_alt"]), p["rel_alt"] > AIRBORNE_M)
        tracks[d] = points
    least = math.inf
    for one, other in pairs:
        a, b = tracks[one], tracks[other]
        common = sorted(a.keys() & b.keys())
        for t in common:  # a single moment in common counts too
            if a[t][1] and b[t][1]:
                least = min(least, math.dist(a[t][0], b[t][0]))
        for t0, t1 in itertools.pairwise(common):
            if (a[t0][1] and b[t0][1]) or (a[t1][1] and b[t1][1]):
                least = min(least, closest_approach(a[t0][0], a[t1][0], b[t0][0], b[t1][0]))
    return least


def metrics(result: dict[str, Any], served: tuple[str, ...]) -> Metrics:
    record = result["mission"]
    return Metrics(
        status=f"{record['status']} ({record['cause']})",
        longest_gap_s=max(longest_gap(result, d) for d in served),
        connected=min(connected_share(result, d) for d in served),
        relays=len(relays_flown(result, served)),
        battery=battery_spent(result),
        separation_m=least_separation(result, served),
    )


def table(rows: list[tuple[str, Metrics]]) -> str:
    lines = ["| experiment | mission | longest telemetry gap | connected | relays | battery spent | least separation |",
             "|---|---|---|---|---|---|---|"]
    for name, m in rows:
        sep = "-" if math.isinf(m.separation_m) else f"{m.separation_m:.1f} m"
        lines.append(f"| {name} | {m.status} | {m.longest_gap_s:.1f} s | {m.connected:.0%} | {m.relays} | {m.battery:.2f} | {sep} |")
    return "\n".join(lines)
