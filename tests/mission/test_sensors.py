"""Simulated sensors (thesis example 21) and the ground's handling of any sensor type.

`fleet sensor temperature` runs for real next to a `fleet agent --fc sim` on a Zenoh
router and publishes what the heat field says where the drone's telemetry puts it;
a mission reads a sensor type the ground has never heard of like any other.
"""

from __future__ import annotations

import asyncio
import subprocess
import textwrap
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.compose import SimField
from dronefleet.schemas.codec import decode_sensor, encode
from dronefleet.schemas.geo import destination
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import SensorReading
from dronefleet.sim.heat_field import HeatSource, temperature_at
from dronefleet.sim.world import DroneSpec, World
from tests.harness import ChildProcess, GroundProcess, Operator, fleet_command, stop_all
from tests.ports import free_udp_base
from tests.waiting import Collector, until

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
    """A humidity sensor program the ground has never heard of: assign by it, read it
    (one it does not carry is not there: reading it names the drone, issue 59)."""
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

    record, log = await _beside(field, humidity(), '''
        d = assign(sensor="humidity")
        first = d.sensor.humidity
        wait(d)
        wait(d)
        print(f"{d.id} humidity {first} then {d.sensor.humidity}; temperature {hasattr(d.sensor, 'temperature')}")
        assert d.sensor.humidity > first
    ''')
    assert (record.status, record.cause) == ("finished", "success"), record.message
    assert "Assigned drone02 (a drone with humidity)" in log
    (line,) = [m for m in log if "humidity" in m and m.startswith("drone02")]
    assert line.endswith("temperature False")


PLUME = {"gas": {"co_ppm": {"background": 3, "sources": [{"lat": LAT, "lon": LON, "radius": 80, "peak": 163}],
                            }, "no2_ppb": {"background": 12}}}


async def test_fleet_sim_runs_any_declared_type_and_the_worlds_field_sensors_as_sensor_programs(tmp_path: Path) -> None:
    """`fleet sim --agents` (no radio) starts a `fleet sensor simulate` per drone sensor the
    world reads and per field sensor it places: a gas reading with the world's fields
    where the drone stands, the field sensor listed at the ground with its own; its
    liveliness goes with the sim."""
    pole = destination(LAT, LON, 40, 90)
    start = destination(LAT, LON, 20, 0)
    world = tmp_path / "world.yml"
    world.write_text(yaml.safe_dump({
        "origin": {"lat": LAT, "lon": LON, "alt": 8.2},
        "drones": [{"id": "drone01", "lat": start[0], "lon": start[1], "sensors": ["gas"]}],
        "fields": PLUME, "field_sensors": [{"id": "gas07", "type": "gas", "lat": pole[0], "lon": pole[1]}],
        "field_sensor_rate_ms": 200,
    }))
    ground = GroundProcess(tmp_path)
    children: list[ChildProcess] = [ground]
    try:
        await ground.ready()
        sim = ChildProcess(fleet_command("sim", str(world), "--agents", "--connect", ground.endpoint,
                                         "--base-port", str(free_udp_base(1) + 1)), tmp_path / "sim.log")
        children.append(sim)
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            async def gas_of_drone() -> dict[str, Any] | None:
                r = await http.get("/drone/drone01")
                found = [s for s in r.json().get("sensors") or [] if s["type"] == "gas"] if r.status_code == 200 else []
                return found[0] if found else None

            async def gas07() -> dict[str, Any] | None:
                r = await http.get("/sensor/gas07")
                return r.json() if r.status_code == 200 and r.json()["readings"] else None

            reading = await until(gas_of_drone, 60, f"drone01's gas reading at the ground\n{sim.output()[-2000:]}")
            # 163 - 160 * 20 / 80 where the drone stands, and the background of no2_ppb
            assert reading["fields"] == {"co_ppm": pytest.approx(123, abs=0.5), "no2_ppb": 12}, reading
            field = await until(gas07, 30, "field sensor gas07 at the ground")
            assert field["alive"] is True and field["readings"][-1]["fields"]["co_ppm"] == pytest.approx(83, abs=0.5), field
            assert "field sensor gas07 (gas) started" in sim.output() and "gas sensor of drone01 started" in sim.output()
            assert sim.stop() == 0
            await until(lambda: _not_alive(http, "gas07"), 20, "gas07's liveliness gone with the sim")
    finally:
        stop_all(reversed(children))


async def _not_alive(http: httpx.AsyncClient, sensor_id: str) -> bool:
    r = await http.get(f"/sensor/{sensor_id}")
    return r.status_code == 404 or r.json()["alive"] is False


async def test_fleet_sensor_simulate_publishes_a_worlds_field_sensor(router: ZenohBus, client: ZenohBus, endpoint: str,
                                                                     tmp_path: Path) -> None:
    pole = destination(LAT, LON, 60, 180)
    world = tmp_path / "world.yml"
    world.write_text(yaml.safe_dump({"fields": PLUME, "field_sensor_rate_ms": 100,
                                     "field_sensors": [{"id": "gas07", "type": "gas", "lat": pole[0], "lon": pole[1]}]}))
    readings = Collector()
    client.subscribe(Keys().field_sensor("gas07", "gas"), lambda s: readings(decode_sensor(s.payload)))
    done = await asyncio.to_thread(
        subprocess.run, fleet_command("sensor", "simulate", "--world", str(world), "--field", "gas07", "--connect", endpoint, "--count", "3"),
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    reading: SensorReading = await readings.wait_for(lambda r: True, 10, "a gas07 reading")
    assert reading.sensor_id == "gas07" and reading.type == "gas" and reading.position is not None
    assert reading.fields == {"co_ppm": pytest.approx(43, abs=0.01), "no2_ppb": 12}  # 163 - 160 * 60 / 80
    assert reading.position.lat == pytest.approx(pole[0])
    assert len([line for line in done.stdout.splitlines() if line.startswith("gas07 gas")]) == 3, done.stdout


async def test_a_carried_type_without_fields_is_announced_without_values_as_fast_time_does() -> None:
    from dronefleet.bus.memory import MemoryBus, MemoryNetwork
    from dronefleet.sim.sensors import world_sensor_program

    world = World(drones=[DroneSpec(id="d1", sensors=["sonar"])])
    program, about = world_sensor_program(world, drone_id="d1", kind="sonar")
    assert "announced without values" in about
    bus = MemoryBus(MemoryNetwork())
    lines: list[str] = []
    task = asyncio.ensure_future(program(bus, lines.append))
    try:
        await until(lambda: lines, 5, "an announced reading")
    finally:
        task.cancel()
    assert lines[0] == "d1 sonar None"


async def test_a_reading_with_fields_reads_by_name_as_attribute_and_as_item() -> None:
    """`fields` carry names from configuration (`pm2.5` cannot be an attribute): a
    mission reads each both ways; an undeclared name is None either way (issue 56)."""
    field = SimField(World(), 2)
    await field.start()
    bus = field._bus()

    async def air() -> None:
        while True:
            bus.publish(Keys().sensor("drone02", "air"), encode(SensorReading(
                drone_id="drone02", timestamp=field.clock.time_ms(), type="air", fields={"pm2.5": 12.0, "co_ppm": 4.0})))
            await field.clock.sleep(0.5)

    record, log = await _beside(field, air(), '''
        d = assign(sensor="air")
        wait(d)
        a = d.sensor.air
        print(f"pm {a['pm2.5']} co {a['co_ppm']} = {a.co_ppm}; none {a['no2']}")
    ''')
    assert (record.status, record.cause) == ("finished", "success"), record.message
    assert "pm 12.0 co 4.0 = 4.0; none None" in log, log


async def _beside(field: SimField, sensor: Coroutine[Any, Any, None], script: str) -> tuple[Any, list[str]]:
    """Run `script` in `field` while `sensor` publishes; the record and the mission's log.
    The field is closed after."""
    task = asyncio.ensure_future(sensor)
    try:
        record = await field.run_mission(textwrap.dedent(script), max_s=60)
        return record, [line.message for line in field.mission_log(record.mission_id)]
    finally:
        task.cancel()
        await field.close()

