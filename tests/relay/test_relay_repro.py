"""The relay in the worlds users wrote (issues 53 and 78), read from `../shared/repro/` and
run exactly as given, each with the seed its README names:

- `relay_short_radio`: the world file's default layout (`count: 5`), a radio good to
  40 m and lost at 70 m, one drone surveying ~117 m out;
- `relay_two_workers_close`: 12 drones, radio 82/129 m, two workers about 200 m out (a
  relay coming down at its home as a worker flew home under it came within 3.85 m);
- `relay_two_workers_stuck`: radio 115/178 m, workers 240 and 320 m out (a worker
  released from its hold never finished; the mission met its time limit);
- `relay_cluster_short_radio`: seven drones in a cluster beside the laptop, radio
  31/57 m, one worker 85 m out (its failsafe brought it home; the mission failed
  `cmd_exec`).

Each must finish, the ground must hear every worker at least every 3 s, and no two
flying drones come within 5 m, judged in continuous time (relay/ways.py
`closest_approach`)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from dronefleet import relay_experiments as rx
from tests.harness import fleet_command

REPRO = Path(__file__).resolve().parents[3] / "shared" / "repro"
ROUND_OFF_M = 1e-6  # two drones taking off side by side at the layout's 5 m


@pytest.mark.slow(12)
@pytest.mark.parametrize(("name", "seed", "workers"), [
    ("relay_short_radio", 5, ["drone01"]),
    ("relay_two_workers_close", 10, ["drone01", "drone02"]),
    ("relay_two_workers_stuck", 16, ["drone01", "drone02"]),
    ("relay_cluster_short_radio", 13, ["drone01"]),
])
def test_the_repro_world_finishes_with_its_workers_heard_and_drones_apart(
        name: str, seed: int, workers: list[str], tmp_path: Path) -> None:
    script, world = REPRO / f"{name}.py", REPRO / f"{name}.yml"
    assert script.is_file() and world.is_file(), f"the reproduction is read from {REPRO}"
    run = subprocess.run([*fleet_command("mission", "simulate", str(script), "--world", str(world), "--seed", str(seed),
                                         "--max-time", "2400", "--out", str(tmp_path), "--no-plots")],
                         capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    result = json.loads((tmp_path / "result.json").read_text())
    mission = result["mission"]
    assert (mission["status"], mission["cause"]) == ("finished", "success"), (mission, run.stdout[-3000:])
    gaps = {w: round(rx.longest_gap(result, w), 1) for w in workers}
    assert all(gap < 3.0 for gap in gaps.values()), f"workers unheard for (s): {gaps}"
    everyone = [(a, b) for i, a in enumerate(result["drones"]) for b in list(result["drones"])[i + 1:]]
    least = rx.least_distance(result, everyone)
    assert least >= 5.0 - ROUND_OFF_M, f"two flying drones {least:.2f} m apart"


def test_on_links_that_never_fail_both_modes_finish_and_every_relay_lands(tmp_path: Path) -> None:
    """The relay examples without a radio model (as a preflight flies them: no links are
    simulated): the probe's hops all hold, so none brackets the hop. The worker goes once
    the proven hop reaches its goal, and a probe no chain took goes home (the worker
    waited 600 s at the laptop, then the probe hovered to the time limit)."""
    examples = Path(__file__).resolve().parents[2] / "examples"
    for script in ("relay_mapping.py", "relay_two_ways.py"):
        world = examples / "worlds" / ("relay.yml" if script == "relay_mapping.py" else "relay_two_ways.yml")
        out = tmp_path / script
        run = subprocess.run([*fleet_command("mission", "simulate", str(examples / script), "--world", str(world),
                                             "--no-radio", "--max-time", "1800", "--out", str(out), "--no-plots")],
                             capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
        result = json.loads((out / "result.json").read_text())
        mission = result["mission"]
        assert (mission["status"], mission["cause"]) == ("finished", "success"), (script, mission, run.stdout[-3000:])
        for drone_id, track in result["drones"].items():
            assert track["samples"][-1]["rel_alt"] < 0.5, (script, drone_id, track["samples"][-1])
