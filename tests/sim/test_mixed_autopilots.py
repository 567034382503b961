"""A PX4 drone and an ArduCopter drone in one mission (issue 58), on real processes:
`fleet sim --autopilot px4,ardupilot`, a `fleet agent` on each (real libmavsdk),
`fleet ground` and the HTTP API. Concurrent subroutines wait on each other through a
channel and each flies a task bundle; a health flag flickering on the ArduCopter in
flight is a warning, and the mission finishes."""

from __future__ import annotations

from pathlib import Path

import pytest

from dronefleet.sim.faults import send_fault
from tests.harness import GroundFleet, SimProcess, ended, submit
from tests.waiting import until

pytestmark = pytest.mark.integration

MISSION = '''
def px4_part():
    arm(px4)
    takeoff(px4, 4 * m)
    channel.px4_up = True
    done = push(px4, [step.move(forward=10 * m), step.move(right=6 * m)], timeout=120 * s)
    channel.px4_bundle = done.state
    land(px4)

def ardupilot_part():
    channel.px4_up  # takes off once the PX4 drone is up
    arm(copter)
    takeoff(copter, 3 * m)
    done = push(copter, [step.move(forward=10 * m), step.move(left=6 * m)], timeout=120 * s)
    print(f"bundles: ardupilot {done.state}, px4 {channel.px4_bundle}")
    land(copter)

px4 = assign("drone01")
copter = assign("drone02")
wait(run(px4_part), run(ardupilot_part))
'''


@pytest.mark.slow(35)
async def test_a_px4_and_an_ardupilot_drone_fly_one_mission_with_a_channel_and_a_bundle_each(tmp_path: Path) -> None:
    sim = SimProcess(tmp_path, n=2, extra_args=["--autopilot", "px4,ardupilot"])
    fleet = GroundFleet(tmp_path, {"drone01": sim.fc_url(0), "drone02": sim.fc_url(1)})
    try:
        async with fleet.client() as http:
            mission_id = await submit(http, MISSION, "mixed")

            # A health flag that drops for a moment on the ArduCopter in flight is a warning,
            # not the end of the mission (issue 58 part 3, on this personality too).
            async def copter_flying() -> bool:
                telem = (await http.get("/drone/drone02", params={"data": "telem"})).json().get("telem") or {}
                return telem.get("landed_state") == "in_air"
            await until(copter_flying, 60, "drone02 in the air")
            assert (await send_fault("drone02", "health_failure", "global_position", sim.control))["ok"]

            async def warned() -> bool:
                return any("drone02 - Health check failing: global_position" in line
                           for line in (await http.get("/drone/logs")).text.splitlines())
            await until(warned, 10, "the warning of drone02's failing check")
            assert (await send_fault("drone02", "health_ok", None, sim.control))["ok"]
            record = await ended(http, mission_id, 240)
            messages = [line["message"] for line in record["log"]]
            assert (record["status"], record["cause"]) == ("finished", "success"), messages[-8:]
            assert "bundles: ardupilot done, px4 done" in messages, messages
            for drone_id in ("drone01", "drone02"):
                telem = (await http.get(f"/drone/{drone_id}", params={"data": "telem"})).json()["telem"]
                assert telem["landed_state"] == "on_ground", (drone_id, telem)
        log = (tmp_path / f"sim-{sim.base_port}.log").read_text()
        assert "(ardupilot)" in log  # drone02's status lines name ArduCopter's modes
    finally:
        try:
            fleet.stop()
        finally:  # the simulator too, also when an agent would not stop
            sim.stop()
