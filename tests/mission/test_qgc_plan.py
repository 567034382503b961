"""`fleet mission import` (SPEC §13): QGroundControl plans into mission scripts.

`tests/plans/PX4SITL-PX4-MultiRotor.plan` is a plan written by QGroundControl, from its
repository (test/plans/, commit ece1cda; QGroundControl is dual-licensed Apache-2.0 /
GPLv3): frames 3 and 0, a speed change, a loiter, a ROI item and two terrain-relative
waypoints without terrain data. The plan with a fence is written here, as
QGroundControl writes one (its 4-space JSON, `SimpleItem`s, a survey `ComplexItem`).
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from dronefleet.compose import SimField
from dronefleet.ground.config import GroundConfig
from dronefleet.mission.script.qgc_plan import NotAPlan, Waypoint, export_plan, import_plan
from dronefleet.mission.script.sandbox import check_mission
from dronefleet.schemas.config_loading import load_config
from dronefleet.schemas.fence import Geofence
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.world import DroneSpec, Spot, World
from tests.harness import fleet_command

PLANS = Path(__file__).parents[1] / "plans"
QGC_PLAN = PLANS / "PX4SITL-PX4-MultiRotor.plan"
ORIGIN = World().origin


def _item(command: int, frame: int, params: list[Any], number: int) -> dict[str, Any]:
    return {"autoContinue": True, "command": command, "doJumpId": number, "frame": frame, "params": params,
            "type": "SimpleItem"}


def fenced_plan() -> tuple[dict[str, Any], list[tuple[float, float, float]]]:
    """A square flown at 12 m above home with a hold, a delay, a survey left out, and a
    fence of every kind; the waypoints (lat, lon, metres above home) it must pass."""
    wps = [(*destination(ORIGIN.lat, ORIGIN.lon, 30, bearing), 12.0) for bearing in (0, 90, 180)]
    corners = [list(destination(ORIGIN.lat, ORIGIN.lon, 200, b)) for b in (45, 135, 225, 315)]
    items = [
        _item(22, 3, [0, 0, 0, None, ORIGIN.lat, ORIGIN.lon, 10], 1),
        _item(16, 3, [2, 0, 0, None, wps[0][0], wps[0][1], 12], 2),  # hold 2 s
        {"type": "ComplexItem", "complexItemType": "survey", "version": 5},
        _item(16, 3, [0, 0, 0, None, wps[1][0], wps[1][1], 12], 4),
        _item(112, 2, [3, 0, 0, 0, 0, 0, 0], 5),  # condition delay 3 s
        _item(16, 0, [0, 0, 0, None, wps[2][0], wps[2][1], ORIGIN.alt + 12], 6),  # AMSL
        _item(206, 2, [0, 0, 0, 0, 0, 0, 0], 7),  # camera trigger distance: not carried over
        _item(20, 2, [0, 0, 0, 0, 0, 0, 0], 8),
    ]
    plan = {
        "fileType": "Plan", "groundStation": "QGroundControl", "version": 1,
        "geoFence": {"version": 2,
                     "polygons": [{"inclusion": True, "polygon": corners, "version": 1},
                                  {"inclusion": False, "polygon": corners[:3], "version": 1}],
                     "circles": [{"circle": {"center": [ORIGIN.lat, ORIGIN.lon], "radius": 300}, "inclusion": True,
                                  "version": 1}]},
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 15, "hoverSpeed": 5,
                    "plannedHomePosition": [ORIGIN.lat, ORIGIN.lon, ORIGIN.alt], "items": items},
        "rallyPoints": {"version": 2, "points": [[ORIGIN.lat, ORIGIN.lon, 20]]},
    }
    return plan, wps


def test_a_qgroundcontrol_plan_becomes_a_script_that_passes_the_sandbox() -> None:
    imported = import_plan(QGC_PLAN.read_text(), "drone01", source=QGC_PLAN.name)
    assert check_mission(imported.script) == []
    lines = [line.split("  #")[0] for line in imported.script.splitlines()[1:]]
    assert lines == [
        "d = assign('drone01')", "launch = d.home", "arm(d)", "takeoff(d, 30*m)",
        "move(d, lat=47.4104747, lon=8.565406, alt=launch.alt + 60*m)",
        "speed = 10*m/s",
        "move(d, lat=47.397, lon=8.585312, alt=638.056*m, speed=speed)",
        "move(d, lat=47.3700507, lon=8.5455, alt=launch.alt + 100*m, speed=speed)",
        "sleep(30*s)",
        "move(d, lat=47.397, lon=8.505688, alt=launch.alt + 70*m, speed=speed)",
        "move(d, lat=47.4194578, lon=8.5189587, alt=launch.alt + 15*m, speed=speed)",
        "move(d, lat=47.3996949, lon=8.5455, speed=speed)", "land(d)",
    ]
    assert imported.left_out == [
        "item 5: MAV_CMD 195 is not carried over",
        "item 6: waypoint without an altitude (terrain-relative altitudes need terrain data)",
        "item 8: waypoint without an altitude (terrain-relative altitudes need terrain data)",
    ]
    assert imported.geofence is None


async def test_an_imported_plan_flies_through_every_waypoint_in_fast_time() -> None:
    plan, wps = fenced_plan()
    imported = import_plan(json.dumps(plan, indent=4), "drone01")
    field = SimField(World(), 1)
    await field.start()
    try:
        record = await field.run_mission(imported.script, max_s=900)
        assert record.status == "finished", (record, imported.script)
        samples = field.result(record)["drones"]["drone01"]["samples"]
    finally:
        await field.close()
    for lat, lon, above_home in wps:
        nearest = min(samples, key=lambda s: distance_m(s["lat"], s["lon"], lat, lon))
        assert distance_m(nearest["lat"], nearest["lon"], lat, lon) < 2.0, (lat, lon)
        assert nearest["rel_alt"] == pytest.approx(above_home, abs=1.0)
    assert samples[-1]["rel_alt"] < 0.5 and distance_m(samples[-1]["lat"], samples[-1]["lon"], ORIGIN.lat, ORIGIN.lon) < 2


async def test_qgroundcontrols_own_plan_flies_to_its_end_through_every_waypoint_it_carried_over() -> None:
    """PX4SITL-PX4-MultiRotor.plan (QGroundControl's test plans): 2 km legs around
    Zurich, a loiter, AMSL and relative altitudes; the three items it cannot carry over
    are named, and the drone passes every other waypoint within 2 m, at its altitude."""
    plan = json.loads(QGC_PLAN.read_text())
    lat, lon, alt = plan["mission"]["plannedHomePosition"]
    imported = import_plan(QGC_PLAN.read_text(), "drone01")
    assert [line.split(":")[0] for line in imported.left_out] == ["item 5", "item 6", "item 8"]
    assert len(imported.waypoints) == 5 and imported.end == "land"
    # its waypoints reach 150 m above home: a site that allows that says so (the default ceiling is 120 m)
    world = World(origin=Spot(lat=lat, lon=lon, alt=alt), drones=[DroneSpec(id="drone01")], geofence=Geofence(max_alt_m=200))
    field = SimField(world, 1)
    await field.start()
    try:
        record = await field.run_mission(imported.script, max_s=3600)
        samples = field.result(record)["drones"]["drone01"]["samples"]
    finally:
        await field.close()
    assert (record.status, record.cause) == ("finished", "success"), record.message
    for w in imported.waypoints:
        nearest = min(samples, key=lambda s: distance_m(s["lat"], s["lon"], w["lat"], w["lon"]))
        assert distance_m(nearest["lat"], nearest["lon"], w["lat"], w["lon"]) < 2.0, w
        assert nearest["rel_alt"] == pytest.approx(w["alt"], abs=1.5), (w, nearest["rel_alt"])
    assert samples[-1]["rel_alt"] < 0.5


@pytest.mark.integration
def test_the_cli_names_what_it_leaves_out_and_writes_the_fence_the_ground_reads(tmp_path: Path) -> None:
    plan, _ = fenced_plan()
    source = tmp_path / "square.plan"
    source.write_text(json.dumps(plan, indent=4))
    script, fence = tmp_path / "square.py", tmp_path / "fence.yml"
    done = subprocess.run(fleet_command("mission", "import", str(source), "--drone", "drone02", "--out", str(script),
                                        "--fence-out", str(fence)), capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    named = [line.removeprefix(f"{source}: ") for line in done.stderr.splitlines() if line.startswith(str(source))]
    assert named == [
        "item 3: complex item 'survey' (a survey, corridor or structure scan) is not carried over",
        "item 7: MAV_CMD 206 is not carried over",
        "geofence polygon 2: an exclusion polygon is not applied (the ground's fence is one inclusion polygon)",
        "geofence circle 1: not applied (the ground's fence is a polygon)",
        "rally point 1: not applied (returns go home)",
    ]
    assert script.read_text().splitlines()[1] == "d = assign('drone02')"
    config = load_config(GroundConfig, fence, {"data_dir": str(tmp_path)})
    assert [list(v) for v in config.geofence.polygon] == plan["geoFence"]["polygons"][0]["polygon"]


@pytest.mark.integration
@pytest.mark.parametrize(("content", "names"), [
    ("not json at all", "not JSON"),
    ('{"fileType": "Mission"}', '"fileType": "Plan"'),
    ('{"fileType": "Plan", "mission": {"version": 1, "items": []}}', "only version 2"),
])
def test_a_file_that_is_not_a_plan_is_exit_2_naming_why(tmp_path: Path, content: str, names: str) -> None:
    source = tmp_path / "x.plan"
    source.write_text(content)
    done = subprocess.run(fleet_command("mission", "import", str(source)), capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and names in done.stderr and "Traceback" not in done.stderr, done
    with pytest.raises(NotAPlan):
        import_plan(content)


def test_junk_inside_a_plan_is_named_never_a_crash() -> None:
    plan = {"fileType": "Plan", "mission": {"version": 2, "items": [
        "not an item", {"type": "SimpleItem", "command": 16, "frame": 3, "params": [0, 0, 0]},
        {"type": "SimpleItem", "command": 16, "frame": 10, "params": [0, 0, 0, None, 40.6, -8.6, 20]},
        {"type": "SimpleItem", "command": 93, "frame": 2, "params": [-1, 12, 30, 0, 0, 0, 0]},
    ]}, "geoFence": {"polygons": [{"inclusion": True, "polygon": [[40.6, "x"], [1], None]}], "circles": "junk"},
        "rallyPoints": []}
    imported = import_plan(json.dumps(plan))
    assert imported.left_out == [
        "item 1: not an item object",
        "item 2: malformed (a command, a frame and seven params expected)",
        "item 3: waypoint in frame terrain (only 3, relative to home, or 0, AMSL)",
        "item 4: a delay until a time of day (param 1 of -1) is not carried over",
        "geofence polygon 1: not applied (not 3 or more [lat, lon] vertices)",
    ]
    assert imported.geofence is None and check_mission(imported.script) == []


def test_an_exported_waypoint_plan_has_the_shape_qgroundcontrol_writes_and_imports_back_to_the_same_waypoints() -> None:
    """SPEC §13: the dashboard exports a waypoint plan as a `.plan` QGroundControl opens.
    Its keys are those of a plan QGroundControl wrote (tests/plans/), and importing it
    gives the same waypoints, holds, speeds and end, with nothing left out."""
    written = json.loads((PLANS / "PX4SITL-PX4-MultiRotor.plan").read_text())
    home = (40.634125, -8.660336, 8.2)
    points = [Waypoint(40.6345, -8.6600, 20.0), Waypoint(40.6349, -8.6596, 25.0, hold_s=5.0, speed=4.0),
              Waypoint(40.6352, -8.6601, 25.0, speed=4.0)]
    fence = [[40.633, -8.662], [40.637, -8.662], [40.637, -8.657], [40.633, -8.657]]
    plan = export_plan(points, home, takeoff_alt=15.0, end="land", fence=fence)
    assert sorted(plan) == sorted(written) and sorted(plan["mission"]) == sorted(written["mission"])
    their_keys = {tuple(sorted(i)) for i in written["mission"]["items"] if i.get("type") == "SimpleItem"}
    assert {tuple(sorted(i)) for i in plan["mission"]["items"]} <= their_keys
    assert plan["mission"]["plannedHomePosition"] == list(home)
    back = import_plan(json.dumps(plan), "drone01", "export.plan")
    assert back.left_out == [] and back.geofence == {"polygon": fence}
    moves = re.findall(r"move\(d, lat=([-\d.]+), lon=([-\d.]+), alt=launch\.alt \+ ([\d.]+)\*m(, speed=speed)?\)", back.script)
    assert [(float(a), float(b), float(c)) for a, b, c, _ in moves] == [(w.lat, w.lon, w.alt) for w in points]
    assert [bool(s) for *_, s in moves] == [False, True, True]
    assert "takeoff(d, 15*m)" in back.script and "speed = 4*m/s" in back.script
    assert "sleep(5*s)  # item 4: hold" in back.script and back.script.rstrip().endswith("land(d)  # item 6")
    assert "home(d)" in import_plan(json.dumps(export_plan(points, home, 15.0, end="return"))).script
    with pytest.raises(ValueError, match="end must be one of"):
        export_plan(points, home, 15.0, end="orbit")
