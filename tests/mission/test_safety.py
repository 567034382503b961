"""Flight safety at the ground and in missions (SPEC §11, issue 18), in fast time: the
geofence refused at the ground (409 geofence) and at the agent, missions failing with
cause `geofence`, `return` always allowed, and deconfliction (409 conflict; a mission's
`move(..., wait_clear=True)` waits for the spot instead)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from dronefleet.agent.config import AgentConfig
from dronefleet.compose import SimField
from dronefleet.ground.config import GroundConfig
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.fence import Geofence
from dronefleet.schemas.geo import destination
from dronefleet.sim.world import DroneSpec, Fault, Spot, World

BASE = (40.633490, -8.660815)


def at(north_m: float, east_m: float) -> tuple[float, float]:
    lat = destination(*BASE, abs(north_m), 0 if north_m >= 0 else 180)[0]
    lon = destination(*BASE, abs(east_m), 90 if east_m >= 0 else 270)[1]
    return lat, lon


# 100 m x 100 m around the drones, the north-east quarter cut away (concave at 20, 20).
L_FENCE = Geofence(polygon=[at(-50, -50), at(50, -50), at(50, 20), at(20, 20), at(20, 50), at(-50, 50)], max_alt_m=40)


def world(n: int = 2) -> World:
    return World(origin=Spot(lat=BASE[0], lon=BASE[1], alt=8.2),
                 drones=[DroneSpec(id=f"drone0{i + 1}", lat=BASE[0], lon=at(0, 8 * i)[1]) for i in range(n)])


async def fly(script: str, tmp_path: Path, fence: Geofence | None = None, agent_fence: Geofence | None = None,
              n: int = 2) -> tuple[Any, list[str], SimField]:
    sim = SimField(world(n), ground_config=GroundConfig(data_dir=str(tmp_path), geofence=fence or Geofence()),
                   data_dir=tmp_path, agent_config=AgentConfig(telemetry_rate_ms=200, geofence=agent_fence or Geofence()))
    await sim.start()
    try:
        record = await sim.run_mission(script, max_s=300)
        return record, [line.message for line in sim.mission_log(record.mission_id)], sim
    finally:
        await sim.close()


FLY_OUT = """
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=30*m)
print("inside")
move(d, forward=40*m)
print("outside")
"""


async def test_a_verb_the_fence_refuses_at_the_ground_fails_the_mission_with_cause_geofence(tmp_path: Path) -> None:
    record, log, _ = await fly(FLY_OUT, tmp_path, fence=L_FENCE)
    assert (record.status, record.cause) == ("failed", "geofence"), (record, log)
    assert "inside" in log and "outside" not in log, log
    assert "is outside the fence" in (record.message or ""), record.message


async def test_the_agent_refuses_what_the_ground_let_through_and_the_mission_fails_with_cause_geofence(
        tmp_path: Path) -> None:
    """The ground has no fence here (a second ground, an operator's own tool: any other
    way); the agent's own fence refuses the flight with reason `geofence`."""
    record, log, _ = await fly(FLY_OUT, tmp_path, agent_fence=L_FENCE)
    assert (record.status, record.cause) == ("failed", "geofence"), (record, log)
    assert "outside" not in log and "geofence: the target" in (record.message or ""), record.message


async def test_a_path_across_the_fence_with_both_ends_inside_is_refused_and_return_always_goes(tmp_path: Path) -> None:
    script = """
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, to=position(LAT1, LON1))
print("at the west end")
move(d, to=position(LAT2, LON2))
"""
    (lat1, lon1), (lat2, lon2) = at(45, 0), at(0, 45)  # both inside; the line cuts the missing corner
    script = script.replace("LAT1", str(lat1)).replace("LON1", str(lon1)).replace("LAT2", str(lat2)).replace("LON2", str(lon2))
    sim = SimField(world(), ground_config=GroundConfig(data_dir=str(tmp_path), geofence=L_FENCE), data_dir=tmp_path)
    await sim.start()
    try:
        record = await sim.run_mission(script, max_s=300)
        assert (record.status, record.cause) == ("failed", "geofence"), record
        assert "straight path to the target leaves the fence" in (record.message or ""), record.message
        # The ground also refuses a goto with an altitude over the ceiling; return always goes.
        with pytest.raises(CommandRejected) as refused:
            await sim.station.command("drone01", json.dumps({"cmd": "goto", "lat": lat1, "lon": lon1, "alt": 8.2 + 41}).encode())
        assert (refused.value.status, refused.value.code) == (409, "geofence") and "max_alt_m 40" in refused.value.reason
        reply = await sim.station.command("drone01", b'{"cmd": "return"}')
        assert reply.accepted
    finally:
        await sim.close()


SAME_SPOT = """
a, b = assign("drone01"), assign("drone02")
def go(d, delay):
    arm(d)
    takeoff(d, 10*m)
    sleep(delay)
    move(d, to=position(LAT, LON), alt=d.home.alt + 10*m, WAIT)
    print(f"{d.id} there")
    if WAITS and d.id == "drone01":
        sleep(2*s)
        move(d, right=15*m)
        print(f"{d.id} made room")
wait(run(go, a, 0*s), run(go, b, 1*s))
"""


def same_spot(wait_clear: bool) -> str:
    lat, lon = at(20, 0)
    return (SAME_SPOT.replace("LAT", str(lat)).replace("LON", str(lon)).replace("WAITS", str(wait_clear))
            .replace("WAIT", f"wait_clear={wait_clear}"))


async def test_two_drones_sent_to_one_spot_the_second_is_refused_naming_the_first(tmp_path: Path) -> None:
    record, log, _ = await fly(same_spot(False), tmp_path)
    assert (record.status, record.cause) == ("failed", "cmd_exec"), (record, log)
    assert "goto drone02 refused: conflict: the target is 0.0 m from the target of drone01" in (record.message or ""), record.message


async def test_with_wait_clear_the_second_waits_until_the_first_has_moved_on(tmp_path: Path) -> None:
    record, log, _ = await fly(same_spot(True), tmp_path)
    assert (record.status, record.cause) == ("finished", "success"), (record, log)
    order = [line for line in log if " there" in line or "made room" in line or "waits for" in line]
    assert order[0].startswith("drone02: goto waits for drone01 to clear the spot (conflict: the target is 0.0 m"), order
    assert order[1:] == ["drone01 there", "drone01 made room", "drone02 there"], order


async def test_simulate_gives_the_worlds_fence_to_ground_and_agents_and_draws_it(tmp_path: Path) -> None:
    """`fleet mission simulate --world examples/worlds/fenced.yml`: the thesis's two-drone
    script stays inside and finishes; result.json carries the fence; paths.png draws it
    (its dashed red line is in the image)."""
    import matplotlib.image

    from dronefleet.compose import simulate
    from dronefleet.sim.world import load_world

    examples = Path(__file__).parents[2] / "examples"
    world = load_world(examples / "worlds" / "fenced.yml")
    assert world.geofence is not None and world.geofence.max_alt_m == 50
    result = await simulate((examples / "two_drones.py").read_text(), world, out_dir=tmp_path, name="two_drones.py",
                            plots=True)
    assert (result["mission"]["status"], result["mission"]["cause"]) == ("finished", "success")
    assert [list(v) for v in result["geofence"]["polygon"]] == [list(v) for v in world.geofence.polygon]
    image = matplotlib.image.imread(tmp_path / "paths.png")
    red = (abs(image[..., 0] - 0xD6 / 255) < 0.03) & (abs(image[..., 1] - 0x27 / 255) < 0.03) & (abs(image[..., 2] - 0x28 / 255) < 0.03)
    assert red.sum() > 200, red.sum()  # the fence's outline (tab:red); no other line uses it


async def test_a_world_fence_reaches_the_agents_too(tmp_path: Path) -> None:
    """The same world with the ground's fence turned off by the caller: the agents'
    fence from the world still refuses a flight out (reason geofence)."""
    from dronefleet.sim.world import load_world

    world = load_world(Path(__file__).parents[2] / "examples" / "worlds" / "fenced.yml")
    sim = SimField(world, ground_config=GroundConfig(data_dir=str(tmp_path), geofence=Geofence(min_separation_m=1)),
                   data_dir=tmp_path)
    assert sim.agent_config.geofence == world.geofence and sim.config.geofence.polygon == []
    await sim.start()
    try:
        record = await sim.run_mission(FLY_OUT.replace("40*m", "100*m"), max_s=300)
        assert (record.status, record.cause) == ("failed", "geofence"), record
        assert "geofence: the target" in (record.message or ""), record.message
    finally:
        await sim.close()


async def test_a_drone_a_gust_sets_outside_the_fence_returns_and_its_mission_fails_with_cause_geofence(
        tmp_path: Path) -> None:
    """Nothing the ground sent took it out: the agent finds it outside, returns it
    (failsafe), and the mission that flew it ends with cause `geofence`."""
    gusty = World(origin=Spot(lat=BASE[0], lon=BASE[1], alt=8.2), drones=[
        DroneSpec(id="drone01", lat=BASE[0], lon=BASE[1], faults=[Fault(at_s=30, fault="gust", value=40.0)])])
    script = """
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, right=30*m)
print("near the east edge")
sleep(60*s)
print("still flying")
"""
    sim = SimField(gusty, ground_config=GroundConfig(data_dir=str(tmp_path), geofence=L_FENCE), data_dir=tmp_path,
                   agent_config=AgentConfig(telemetry_rate_ms=200, geofence=L_FENCE))
    await sim.start()
    try:
        record = await sim.run_mission(script, max_s=300)
        log = [line.message for line in sim.mission_log(record.mission_id)]
        assert (record.status, record.cause) == ("failed", "geofence"), (record, log)
        assert "near the east edge" in log and "still flying" not in log, log
        assert "drone01 was found outside the geofence" in (record.message or ""), record.message
        vehicle = sim.vehicles["drone01"]
        assert vehicle.mode == "return_to_launch", vehicle.mode
        await sim.clock.advance(90)  # it flies home and lands: inside again
        north, east, _ = vehicle.local_ned()
        assert not vehicle.in_air and abs(north) < 1 and abs(east) < 1, (vehicle.mode, north, east)
    finally:
        await sim.close()
