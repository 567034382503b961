"""The relay in the first world a user writes (issue 53): `../shared/repro/relay_short_radio.*`
run exactly as given — the world file's default layout (`count: 5`, a row from the
laptop's own spot, 5 m apart), a radio good to 40 m and lost at 70 m, one drone
surveying ~117 m out, `enable("relay")` with nothing else. It must finish, the ground
must hear the surveyor at least every 3 s, and no two flying drones come within 5 m."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from dronefleet import relay_experiments as rx
from tests.harness import fleet_command

REPRO = Path(__file__).resolve().parents[3] / "shared" / "repro"


def test_the_repro_world_finishes_with_the_surveyor_heard_and_drones_apart(tmp_path: Path) -> None:
    script, world = REPRO / "relay_short_radio.py", REPRO / "relay_short_radio.yml"
    assert script.is_file() and world.is_file(), f"the reproduction is read from {REPRO}"
    run = subprocess.run([*fleet_command("mission", "simulate", str(script), "--world", str(world), "--seed", "5",
                                         "--max-time", "1800", "--out", str(tmp_path))],
                         capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    result = json.loads((tmp_path / "result.json").read_text())
    mission = result["mission"]
    assert (mission["status"], mission["cause"]) == ("finished", "success"), (mission, run.stdout[-3000:])
    gap = rx.longest_gap(result, "drone01")
    assert gap < 3.0, f"drone01 unheard {gap:.1f} s"
    everyone = [(a, b) for i, a in enumerate(result["drones"]) for b in list(result["drones"])[i + 1:]]
    least = rx.least_distance(result, everyone)
    assert least >= 5.0, f"two flying drones {least:.1f} m apart"


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
