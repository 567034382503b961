"""Simulated sensors (thesis example 21) and the ground's handling of any sensor type.

`fleet sensor temperature` runs for real next to a `fleet agent --fc sim` on a Zenoh
router and publishes what the heat field says where the drone's telemetry puts it;
a mission reads a sensor type the ground has never heard of like any other.
"""

from __future__ import annotations

import asyncio
import subprocess
import textwrap
from pathlib import Path
from typing import Any

import pytest
import yaml

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.compose import SimField
from dronefleet.schemas.codec import decode_sensor, encode
from dronefleet.schemas.geo import destination
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import SensorReading
from dronefleet.sim.heat_field import HeatSource, temperature_at
from dronefleet.sim.world import World
from tests.harness import Operator, fleet_command
from tests.helpers import Collector

pytestmark = pytest.mark.integration

LAT, LON = 40.633490, -8.660815


def source_at(distance: float, bearing: float, radius: float = 50, temp: float = 60) -> HeatSource:
    lat, lon = destination(LAT, LON, distance, bearing)
    return HeatSource(lat=lat, lon=lon, radius=radius, temp=temp)


def test_heat_field_falls_off_linearly_and_takes_the_hottest_source() -> None:
    centre = source_at(0, 0)
    assert temperature_at(20, [centre], LAT, LON) == pytest.approx(60)
    for d, expected in ((12.5, 50), (25, 40), (37.5, 30), (49.9, 20.08), (50, 20), (80, 20)):
        lat, lon = destination(LAT, LON, d, 45)
        assert temperature_at(20, [centre], lat, lon) == pytest.approx(expected, abs=0.01), d
    cooler = source_at(10, 90, radius=20, temp=100)  # 10 m east: 100 - 80 * 10/20 = 60 here ...
    lat, lon = destination(LAT, LON, 10, 90)  # ... and 100 at its own centre
    assert temperature_at(20, [centre, cooler], lat, lon) == pytest.approx(100, abs=0.01)
    assert temperature_at(20, [], LAT, LON) == 20


async def test_fleet_sensor_temperature_publishes_the_field_where_the_drone_is(
    router: ZenohBus, client: ZenohBus, endpoint: str, agents: Any, operator: Any, tmp_path: Path,
) -> None:
    agents("drone01", fc=f"sim://?lat={LAT}&lon={LON}&alt=8.2", telemetry_rate_ms=100)
    watch: Operator = operator("drone01")
    first = await watch.next_telemetry(lambda t: t.position is not None, 20, "first telemetry")
    assert first.position is not None
    heat = tmp_path / "heat.yml"
    sources = [source_at(20, 0), source_at(30, 180, radius=60, temp=100)]  # 42 °C and 57.5 °C here
    heat.write_text(yaml.safe_dump({
        "rate_ms": 100, "environment_temp": 15,
        "heat_sources": [{"lat": s.lat, "lon": s.lon, "radius": s.radius, "temp": s.temp} for s in sources],
    }))
    readings = Collector()
    client.subscribe(Keys().sensor("drone01", "temperature"), lambda s: readings(decode_sensor(s.payload)))
    done = await asyncio.to_thread(
        subprocess.run,
        fleet_command("sensor", "temperature", "--drone", "drone01", "--config", str(heat), "--connect", endpoint, "--count", "5"),
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )
    assert done.returncode == 0, done.stderr
    expected = temperature_at(15, sources, first.position.lat, first.position.lon)
    assert expected == pytest.approx(100 - 85 * 30 / 60)  # the hotter source wins
    reading: SensorReading = await readings.wait_for(lambda r: True, 10, "a temperature reading")
    assert reading.drone_id == "drone01" and reading.type == "temperature" and reading.unit == "degC"
    assert reading.value == pytest.approx(expected, abs=0.05)
    assert len([line for line in done.stdout.splitlines() if line.startswith("drone01 temperature")]) == 5
    assert f"{expected:.2f}" in done.stdout


def test_fleet_sensor_temperature_refuses_a_bad_config(tmp_path: Path) -> None:
    heat = tmp_path / "heat.yml"
    heat.write_text("heat_sources:\n  - {lat: 40.6, lon: -8.6, radius: 50, temperature: 60}\n")
    done = subprocess.run(fleet_command("sensor", "temperature", "--drone", "drone01", "--config", str(heat)),
                          capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL)
    assert done.returncode == 2
    assert "temperature" in done.stderr and "heat_sources" in done.stderr


async def test_a_mission_reads_and_assigns_by_any_sensor_type() -> None:
    """A humidity sensor program the ground has never heard of: assign by it, read it."""
    field = SimField(World(), 2)
    await field.start()
    bus = field._bus()
    keys = Keys()

    async def humidity() -> None:
        value = 40.0
        while True:
            value += 0.5
            bus.publish(keys.sensor("drone02", "humidity"),
                        encode(SensorReading(drone_id="drone02", timestamp=field.clock.time_ms(), type="humidity", value=value, unit="%")))
            await field.clock.sleep(0.5)

    task = asyncio.ensure_future(humidity())
    try:
        script = textwrap.dedent('''
            d = assign(sensor="humidity")
            first = d.sensor.humidity
            wait(d)
            wait(d)
            print(f"{d.id} humidity {first} then {d.sensor.humidity}; temperature {d.sensor.temperature}")
            assert d.sensor.humidity > first
        ''')
        record = await field.run_mission(script, max_s=60)
        log = [line.message for line in field.mission_log(record.mission_id)]
    finally:
        task.cancel()
        await field.close()
    assert (record.status, record.cause) == ("finished", "success"), record.message
    assert "Assigned drone02 (a drone with humidity)" in log
    (line,) = [m for m in log if "humidity" in m and m.startswith("drone02")]
    assert line.endswith("temperature None")
