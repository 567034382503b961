"""Issue 35 with real processes: agents that say what they are (About), declared sensors
held to their declaration, missions that pick by kind and role, and field sensors played
on the raw wire (SPEC §2 shapes), also on a secured mesh."""

from __future__ import annotations

import asyncio
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.codec import decode_about, encode
from dronefleet.schemas.telemetry import Position, SensorReading
from tests.harness import GroundFleet, ended, fleet_command, make_pki, submit
from tests.waiting import until

pytestmark = pytest.mark.integration
AT = (40.6334, -8.6608)
GAS = {"type": "gas", "fields": {"co_ppm": {"unit": "ppm", "min": 0, "max": 1000}}}
FIELD_AT = Position(lat=40.6340, lon=-8.6608, alt=8.0)


def now_ms() -> int:
    return int(time.time() * 1000)


def spawn(i: int) -> str:
    return f"sim://?lat={AT[0]}&lon={AT[1] + i * 0.0001}&alt=8.2"


async def keep_publishing(bus: ZenohBus, key: str, reading: dict[str, Any], period_s: float = 0.2) -> None:
    while True:
        bus.publish(key, encode(SensorReading(timestamp=now_ms(), **reading)))
        await asyncio.sleep(period_s)


async def logs(http: httpx.AsyncClient) -> str:
    return (await http.get("/drone/logs")).text


async def test_kinds_roles_declared_sensors_and_a_field_sensor_reach_missions(tmp_path: Path) -> None:
    configs: dict[str, dict[str, Any]] = {"drone01": {"kind": "x500-quad", "sensors": [GAS]},
               "drone02": {"kind": "fixed-wing", "roles": ["survey", "relay"]},
               "drone03": {"roles": ["auxiliary"]}}
    fleet = GroundFleet(tmp_path, {"drone01": spawn(0), "drone02": spawn(1), "drone03": spawn(2)},
                        per_agent=configs, sensor_timeout_ms={"gas": 3000})
    tasks: list[asyncio.Task[None]] = []
    sensor_bus = field_bus = None
    try:
        async with fleet.client() as http:
            endpoint = [fleet.ground.endpoint]
            sensor_bus = await ZenohBus.open("client", endpoint)
            # The agent answers a query on its About key, in SPEC's shape.
            about = decode_about(await sensor_bus.query("drone/drone01/about", timeout_s=5))
            assert about.kind == "x500-quad" and about.roles == ["survey"] and about.sensors[0].fields["co_ppm"].max == 1000

            async def infos() -> dict[str, Any] | None:
                found = {d["info"]["drone_id"]: d["info"] for d in (await http.get("/drone", params={"data": "info"})).json()}
                return found if all(found.get(d, {}).get("roles") for d in configs) else None

            info = await until(infos, 15, "every drone's About at the ground")
            assert info["drone01"]["kind"] == "x500-quad" and info["drone01"]["sensors_declared"] == [GAS]
            assert info["drone02"]["roles"] == ["survey", "relay"] and info["drone03"]["roles"] == ["auxiliary"]
            assert info["drone03"]["kind"] == "multicopter"

            # drone01's gas sensor, as a sensor program on its SBC would publish it.
            tasks.append(asyncio.ensure_future(keep_publishing(
                sensor_bus, "drone/drone01/sensor/gas", {"drone_id": "drone01", "type": "gas", "fields": {"co_ppm": 12.5}})))
            sensor_bus.publish("drone/drone01/sensor/gas", encode(SensorReading(
                drone_id="drone01", timestamp=now_ms(), type="gas", fields={"co_ppm": 5000.0})))
            await until(lambda: _contains(logs(http), "Dropped a gas reading outside its declaration: gas.co_ppm 5000"),
                        15, "the out-of-range reading logged")
            # A field sensor on the raw wire: its liveliness token and its readings.
            field_bus = await ZenohBus.open("client", endpoint)
            token = field_bus.announce("sensor/gas07/alive")
            tasks.append(asyncio.ensure_future(keep_publishing(field_bus, "sensor/gas07/gas", {
                "sensor_id": "gas07", "type": "gas", "fields": {"co_ppm": 40.0, "no2_ppb": 7.0}, "position": FIELD_AT}, 0.5)))

            async def listed() -> Any:  # its reading and its token travel apart: either may come first
                body = (await http.get("/sensor", params={"type": "gas"})).json()
                return body if body and body[0]["alive"] is not None else None

            listing = await until(listed, 15, "gas07 in GET /sensor, its token seen")
            assert listing[0]["sensor_id"] == "gas07" and listing[0]["alive"] is True
            assert listing[0]["position"]["lat"] == FIELD_AT.lat and listing[0]["readings"][0]["fields"]["co_ppm"] == 40.0
            assert (await http.get("/sensor/nope")).status_code == 404

            mission = await submit(http, """
a = assign(kind="x500-quad")
r = assign(role="relay")
print("picked", a.id, a.kind, r.id, ",".join(r.roles))
wait(a)
print("co", a.sensor.gas.co_ppm)
near = field_sensors(type="gas", near=a.position, within=500*m)
print("field", [s.id for s in near], near[0].fields.co_ppm, near[0].fields.no2_ppb)
wait(near[0])
print("heard gas07 again")
x = assign(any_drone)
""")
            record = await ended(http, mission, 60)
            lines = [line["message"] for line in record["log"]]
            assert "picked drone01 x500-quad drone02 survey,relay" in lines, lines
            assert "co 12.5" in lines and "field ['gas07'] 40.0 7.0" in lines and "heard gas07 again" in lines, lines
            assert record["status"] == "failed" and record["cause"] == "requirements", record
            assert "only auxiliary drones are free (drone03)" in record["message"], record

            swap = await submit(http, 'd = assign(kind="fixed-wing")\nreplace(d)\nprint("now", d.id)\n')
            record = await ended(http, swap, 60)
            assert record["status"] == "finished", record
            assert "now drone03" in [line["message"] for line in record["log"]], record  # the auxiliary one first

            # The field sensor stops: its token goes, its reading times out, it is forgotten.
            tasks.pop().cancel()
            token.close()

            async def forgotten() -> bool:
                return (await http.get("/sensor/gas07")).status_code == 404

            await until(forgotten, 15, "gas07 forgotten after sensor_timeout_ms")
            text = await logs(http)
            assert "Field sensor gas07: liveliness token lost" in text and "Field sensor gas07: lost gas" in text, text

            # `fleet sensor publish` sends one reading with its position.
            published = subprocess.run(
                fleet_command("sensor", "publish", "--id", "gas08", "--type", "gas", "--at", "40.6341,-8.6609",
                              "--connect", endpoint[0], "co_ppm=12.5"),
                capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
            assert published.returncode == 0, published.stderr
            one = await until(lambda: _json(http.get("/sensor/gas08")), 15, "gas08 at the ground")
            assert one["readings"][0]["fields"] == {"co_ppm": 12.5} and one["position"]["lon"] == -8.6609
    finally:
        for task in tasks:
            task.cancel()
        for bus in (sensor_bus, field_bus):
            if bus is not None:
                await bus.close()
        fleet.stop()


async def _contains(text: Any, needle: str) -> bool:
    return needle in await text


async def _json(response: Any) -> Any:
    r = await response
    return r.json() if r.status_code == 200 else None


async def test_on_a_secured_mesh_a_field_sensor_publishes_only_under_its_own_id(tmp_path: Path) -> None:
    from dronefleet.cli import secured_client

    pki = make_pki(tmp_path / "pki", {"ground": "ground", "gas07": "sensor", "drone02": "drone"})
    security = {"pki_dir": str(pki), "tls": True}
    fleet = GroundFleet(tmp_path, {}, security=security, scheme="tls")
    buses: list[ZenohBus] = []
    try:
        async with fleet.client() as http:
            endpoint = [fleet.ground.endpoint]
            sensor = await ZenohBus.open("client", endpoint, extra=secured_client(pki, "gas07", endpoint))
            drone = await ZenohBus.open("client", endpoint, extra=secured_client(pki, "drone02", endpoint))
            buses += [sensor, drone]

            def reading(sensor_id: str) -> bytes:
                return encode(SensorReading(sensor_id=sensor_id, timestamp=now_ms(), type="gas", value=3.0, position=FIELD_AT))

            async def heard(sensor_id: str) -> bool:
                return (await http.get(f"/sensor/{sensor_id}")).status_code == 200

            async def own_arrives() -> bool:  # sent first, each round: had they passed, they would be there
                sensor.publish("sensor/gas09/gas", reading("gas09"))
                drone.publish("sensor/gas10/gas", reading("gas10"))
                sensor.publish("sensor/gas07/gas", reading("gas07"))
                return await heard("gas07")

            await until(own_arrives, 15, "gas07's own reading at the ground")
            assert not await heard("gas09"), "a sensor certificate published under another sensor's id"
            assert not await heard("gas10"), "a drone certificate published as a field sensor"
    finally:
        for bus in buses:
            await bus.close()
        fleet.stop()
