"""Run-time errors in the field's words, and safe defaults (issue 59), in fast time: a
sensor the drone does not carry is named with the drone and `assign(sensor=…)`; every
script error names its line, subroutine and drone; takeoffs above 120 m are refused
unless the ground's configuration allows more; drones a failed script leaves in the air
are logged with where they were left."""

from __future__ import annotations

from pathlib import Path

import pytest

from dronefleet.compose import SimField
from dronefleet.ground.config import DEFAULT_CEILING_M, GroundConfig
from dronefleet.mission.lifecycle.record import MissionRecord
from dronefleet.schemas.fence import Geofence
from dronefleet.sim.world import DroneSpec, World

WORLD = World(drones=[DroneSpec(id="drone01", sensors=["camera"]), DroneSpec(id="drone02", lat=0.0001, lon=0.0)])


async def fly(script: str, tmp_path: Path, config: GroundConfig | None = None,
              max_s: float = 600) -> tuple[MissionRecord, list[str]]:
    field = SimField(WORLD, ground_config=config or GroundConfig(data_dir=str(tmp_path)), data_dir=tmp_path)
    await field.start()
    try:
        record = await field.run_mission(script, max_s=max_s)
        assert field.manager is not None
        return record, [line.message for line in field.manager.log(record.mission_id)]
    finally:
        await field.close()


async def test_reading_a_sensor_the_drone_does_not_carry_names_the_drone_the_sensor_and_the_fix(tmp_path: Path) -> None:
    record, _ = await fly('d = assign("drone01")\nif d.sensor.temperature > 30:\n    land(d)\n', tmp_path)
    assert (record.status, record.cause) == ("failed", "script")
    assert record.message is not None
    assert "line 2: NoSuchSensor: drone01 carries no temperature sensor (it carries: camera)" in record.message
    assert "assign(sensor='temperature')" in record.message


async def test_a_sensor_the_drone_carries_reads_none_before_its_first_reading_and_hasattr_asks(tmp_path: Path) -> None:
    record, lines = await fly('d = assign("drone01")\nprint(hasattr(d.sensor, "temperature"), hasattr(d.sensor, "camera"))\n',
                              tmp_path)
    assert (record.status, record.cause) == ("finished", "success")
    assert "False True" in lines


async def test_a_script_error_names_its_line_subroutine_and_drone(tmp_path: Path) -> None:
    script = ("def survey(d):\n    arm(d)\n    takeoff(d, 5*m)\n    move(d, forward=d.battery*s)\n"
              "w = run(survey, assign('drone02'))\nwait(w)\n")
    record, lines = await fly(script, tmp_path)
    assert (record.status, record.cause) == ("failed", "script")
    assert record.message is not None
    assert record.message.startswith("line 4: UnitError: forward: expected a distance (m)")
    assert record.message.endswith("(in subroutine survey, on drone02)")
    # it failed in the air: the log says where the drone was left (mission.end_action: hold)
    assert any(line.startswith("drone02: ") and "at mission end" in line and "5.0 m above home" in line for line in lines), lines


@pytest.fixture
def two_dirs(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "default").mkdir()
    (tmp_path / "higher").mkdir()
    return tmp_path / "default", tmp_path / "higher"


async def test_a_takeoff_above_120_m_is_refused_by_default_and_flown_under_a_higher_configured_ceiling(
        two_dirs: tuple[Path, Path]) -> None:
    assert GroundConfig().geofence.max_alt_m == DEFAULT_CEILING_M == 120.0
    script = 'd = assign()\narm(d)\ntakeoff(d, 500*m)\nland(d)\n'
    record, _ = await fly(script, two_dirs[0])
    assert (record.status, record.cause) == ("failed", "geofence")
    assert record.message is not None and "max_alt_m 120 m" in record.message
    higher = GroundConfig(data_dir=str(two_dirs[1]), geofence=Geofence(max_alt_m=600))
    record, _ = await fly(script, two_dirs[1], higher, max_s=3600)  # 500 m up and down
    assert (record.status, record.cause) == ("finished", "success")


@pytest.mark.parametrize("given", [{}, {"polygon": [[0.0, 0.0], [0.0, 0.01], [0.01, 0.01]]}, {"max_alt_m": 300.0}])
def test_the_ceiling_is_120_m_unless_configured(given: dict[str, object]) -> None:
    fence = GroundConfig(geofence=Geofence(**given)).geofence  # type: ignore[arg-type]
    assert fence.max_alt_m == given.get("max_alt_m", 120.0)
