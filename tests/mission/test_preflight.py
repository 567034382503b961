"""A mission that would fail, fails on the ground (issue 59), against real processes:
`fleet ground` (preflight on, as it is by default) and three `fleet agent --fc sim`.

Before a submission flies, the ground flies it in fast time against the fleet as it is;
what would fail is refused (422, and `fleet mission submit` exits 1) naming the line,
the simulated time and the cause, and no drone arms. A valid two-drone mission with a
channel and the replacement plugin passes, reports its prediction and flies."""

from __future__ import annotations

import asyncio
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.codec import encode
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import Position, SensorReading
from tests.harness import GroundFleet, ended, fleet_command
from tests.waiting import until

# One worker runs them all, on the module's one fleet: spread over the workers, each
# started a fleet of its own for its one or two tests. The group holds the other
# modules with a fleet of their own too, one after the other (ADR 0011).
pytestmark = [pytest.mark.integration, pytest.mark.xdist_group("module-fleets")]

DRONES = ("drone01", "drone02", "drone03")
DRAIN_PER_S = 0.004  # the ground's flight_drain_per_s here: a pack lasts about 4 minutes in the air
BOUND_S = 20.0  # mission.preflight_wall_s here: the valid ones took 10 s and more on a busy suite
GAS = {"type": "gas", "fields": {"co_ppm": {"unit": "ppm", "min": 0, "max": 1000}}}
FIELD_SPOT = (40.6341, -8.6609, 8.0)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GroundFleet]:
    fcs = {d: f"sim://?lat=40.633400&lon={-8.660810 + 0.00013 * i:.6f}&alt=8.2" for i, d in enumerate(DRONES)}
    fleet = GroundFleet(tmp_path_factory.mktemp("preflight"), fcs,
                        {"telemetry_rate_ms": 200}, per_agent={"drone03": {"sensors": [{"type": "camera"}]}, "drone01": {"sensors": [GAS]}},
                        mission={"preflight": True, "flight_drain_per_s": DRAIN_PER_S, "preflight_max_s": 900,
                                 # one preflight at a time, bounded well above what the valid ones take here
                                 "preflight_wall_s": BOUND_S, "preflight_concurrency": 1})
    yield fleet
    fleet.stop()


async def _never_armed(http: httpx.AsyncClient) -> None:
    missions = (await http.get("/mission")).json()
    assert missions == [] or all(m["name"] != "refused" for m in missions), missions
    for drone in DRONES:
        telem = (await http.get(f"/drone/{drone}")).json()["telem"]
        assert telem["armed"] is False, (drone, telem)


async def _refused(http: httpx.AsyncClient, source: str) -> dict[str, object]:
    response = await http.post("/mission", content=source.encode(), params={"name": "refused"}, timeout=240)
    assert response.status_code == 422, response.text
    await _never_armed(http)
    return dict(response.json())


@pytest.mark.slow(40)
async def test_what_only_running_shows_is_refused_before_any_drone_arms(http: httpx.AsyncClient, fleet: GroundFleet,
                                                                        tmp_path: Path) -> None:
    await until(lambda: _all_ready(http), 45, "three drones ready")
    # a unit the text cannot show (a variable): the fast-time run fails at line 5
    unit = "d = assign()\narm(d)\ntakeoff(d, 5*m)\nhop = 10*s\nmove(d, forward=hop)\nland(d)\n"
    body = await _refused(http, unit)
    detail = body["detail"]
    assert isinstance(detail, dict) and detail["line"] == 5 and detail["cause"] == "script" and detail["t_s"] > 0, body
    assert "after" in str(body["error"]) and "s simulated at line 5" in str(body["error"]), body
    assert "UnitError: forward: expected a distance (m), got 10 s" in str(body["error"]), body

    # a sensor no drone carries: named, with the drone and the fix
    body = await _refused(http, "d = assign()\narm(d)\ntakeoff(d, 5*m)\nif d.sensor.temperature > 30:\n    land(d)\n")
    assert "line 4" in str(body["error"]) and "carries no temperature sensor" in str(body["error"]), body
    assert "assign(sensor='temperature')" in str(body["error"]), body

    # a battery that runs out halfway: refused with the time it would have
    survey = "d = assign()\narm(d)\ntakeoff(d, 10*m)\nfor i in range(16):\n    move(d, forward=100*m)\n    turn(d, by=90*deg)\nland(d)\n"
    body = await _refused(http, survey)
    detail = body["detail"]
    assert isinstance(detail, dict) and (detail["status"], detail["cause"]) == ("cancelled", "return"), body
    assert 100 < float(detail["t_s"]) < 1 / DRAIN_PER_S, body  # in the air until the pack was nearly empty

    # the CLI says the same and exits 1
    script = tmp_path / "unit.py"
    script.write_text(unit)
    cli = subprocess.run(fleet_command("mission", "submit", "--url", fleet.ground.url, str(script)),
                         capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
    assert cli.returncode == 1, cli
    assert "422: preflight: the mission failed after" in cli.stderr and "at line 5" in cli.stderr, cli.stderr
    await _never_armed(http)

    # a typo is the text's: 400 with line and column, before any preflight
    typo = await http.post("/mission", content=b"d = assign()\ntakeof(d, 5*m)\n")
    assert typo.status_code == 400 and typo.json()["detail"]["line"] == 2, typo.text
    assert "did you mean 'takeoff'" in typo.json()["error"]


@pytest.mark.slow(40)
async def test_a_valid_two_drone_mission_with_a_channel_and_replacement_passes_reports_and_flies(
        http: httpx.AsyncClient) -> None:
    await until(lambda: _all_ready(http), 45, "three drones ready")
    source = """enable("replacement")
a, b = assign("drone01"), assign("drone02")

def first():
    arm(a)
    takeoff(a, 5*m)
    channel.up = True
    move(a, forward=10*m)
    land(a)

def second():
    channel.up
    arm(b)
    takeoff(b, 3*m)
    move(b, right=10*m)
    land(b)

wait(run(first), run(second))
"""
    response = await http.post("/mission", content=source.encode(), params={"name": "valid"}, timeout=240)
    assert response.status_code == 201, response.text
    created = response.json()
    preflight = created["preflight"]
    assert preflight["passed"] is True and (preflight["status"], preflight["cause"]) == ("finished", "success"), preflight
    assert set(preflight["battery_left"]) == {"drone01", "drone02"} and preflight["t_s"] > 5, preflight
    assert all(0 < b < 1 for b in preflight["battery_left"].values()), (preflight["battery_left"], preflight["t_s"])
    final = await ended(http, created["mission_id"], 120)
    assert (final["status"], final["cause"]) == ("finished", "success"), final
    log = [line["message"] for line in (await http.get(f"/mission/{created['mission_id']}")).json()["log"]]
    assert log[0].startswith("Preflight passed: finished success after"), log


async def _all_ready(http: httpx.AsyncClient) -> bool:
    views = (await http.get("/drone")).json()
    return {v["info"]["drone_id"] for v in views if v["info"]["state"] == "ready"} >= set(DRONES)


@pytest.mark.slow(30)
async def test_a_script_that_never_waits_is_refused_at_its_bound_and_holds_up_no_one(http: httpx.AsyncClient) -> None:
    """The preflight's wall bound (mission.preflight_wall_s) ends a script that spins
    without ever waiting on a drone, naming the line it had reached; meanwhile a second
    preflight finds the one slot taken and is answered 503 with Retry-After at once,
    and a submission without a preflight is taken while the spinning one still runs."""
    await until(lambda: _all_ready(http), 45, "three drones ready")
    spin = b"d = assign()\nx = 0\nwhile True:\n    x += 1\n"

    def submit_spinning() -> asyncio.Task[httpx.Response]:
        return asyncio.get_running_loop().create_task(
            http.post("/mission", content=spin, params={"name": "refused"}, timeout=BOUND_S + 30))

    spinning = submit_spinning()

    async def turned_away() -> httpx.Response | None:
        """A second preflight, until it finds the slot the spinning one holds (422 while
        it has not taken it yet; if the second came first, the spinning one is sent again)."""
        nonlocal spinning
        response = await http.post("/mission", content=b"d = assign()\nx = [1][5]\n", params={"name": "refused"})
        if spinning.done() and spinning.result().status_code == 503:
            spinning = submit_spinning()
            return None
        return response if response.status_code == 503 else None

    busy = await until(turned_away, BOUND_S, "a second preflight answered 503")
    assert busy.headers["Retry-After"] == str(int(BOUND_S + 1)), busy.headers
    assert "mission.preflight_concurrency" in busy.json()["error"], busy.text
    unchecked = await http.post("/mission", content=b"d = assign()\nprint('no preflight')\n",
                                params={"name": "unchecked", "preflight": "false"})
    assert unchecked.status_code == 201 and unchecked.json()["preflight"] is None, unchecked.text
    assert not spinning.done(), "the spinning preflight ended before the unchecked submission was taken"
    assert (await ended(http, unchecked.json()["mission_id"], 30))["status"] == "finished"

    refused = await spinning
    assert refused.status_code == 422, refused.text
    detail = refused.json()["detail"]
    assert detail["line"] in (3, 4) and detail["cause"] == "security", detail
    assert "mission.preflight_wall_s" in refused.json()["error"], refused.text
    await _never_armed(http)


@pytest.mark.slow(30)
async def test_a_mission_reading_what_the_ground_has_heard_passes_its_preflight_and_flies(
        http: httpx.AsyncClient, fleet: GroundFleet) -> None:
    """The preflight's world holds what the ground has heard: drone01's gas sensor reads
    42 ppm and a field sensor gas07 stands at its spot reading 40; a mission that reads
    both passes its preflight and flies, printing what the drones read."""
    await until(lambda: _all_ready(http), 45, "three drones ready")
    keys = Keys()
    bus = await ZenohBus.open("client", connect=[fleet.ground.endpoint])
    token = bus.announce(keys.field_sensor_alive("gas07"))

    async def publish() -> None:
        while True:
            now = int(time.time() * 1000)
            bus.publish(keys.sensor("drone01", "gas"), encode(SensorReading(
                drone_id="drone01", timestamp=now, type="gas", fields={"co_ppm": 42.0})))
            bus.publish(keys.field_sensor("gas07", "gas"), encode(SensorReading(
                timestamp=now, type="gas", fields={"co_ppm": 40.0}, sensor_id="gas07",
                position=Position(lat=FIELD_SPOT[0], lon=FIELD_SPOT[1], alt=FIELD_SPOT[2], rel_alt=0.0))))
            await asyncio.sleep(0.5)  # a sensor's own rate, not a wait in the test

    publishing = asyncio.get_running_loop().create_task(publish())
    try:
        async def heard() -> bool:
            drone = (await http.get("/drone/drone01", params={"data": "sensors"})).json()
            field = await http.get("/sensor/gas07")
            return "42" in str(drone) and field.status_code == 200
        await until(heard, 15, "both readings at the ground")
        source = ('d = assign("drone01")\nwait(d)\nprint("co", d.sensor.gas.co_ppm)\n'
                  'ss = field_sensors(type="gas")\ns = ss[0]\nprint("field", s.id, s.fields.co_ppm)\n')
        response = await http.post("/mission", content=source.encode(), params={"name": "sensors"}, timeout=60)
        assert response.status_code == 201, response.text
        assert response.json()["preflight"]["passed"] is True, response.text
        record = await ended(http, response.json()["mission_id"], 60)
        lines = [line["message"] for line in record["log"]]
        assert (record["status"], record["cause"]) == ("finished", "success"), record
        assert "co 42.0" in lines and "field gas07 40.0" in lines, lines
    finally:
        publishing.cancel()
        token.close()
        await bus.close()
