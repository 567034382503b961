"""Missions cannot take the ground down (SPEC §9, issue 16): every mission runs in a
process of its own with `mission.max_memory_mb` and `mission.max_cpu_s`.

A real `fleet ground` and two `fleet agent --fc sim` children. One mission tries to
allocate a hundred gigabytes, one computes a modular power in C for hours, one
spins in the range builtin from the issue (`sum(range(10**12))`): each ends with
cause `security`, while a fourth mission flies and finishes, telemetry keeps flowing
and the ground's own memory stays where it was. A mission stuck in C code is
cancelled within its grace (its process is killed), and the drones of a killed
mission are released.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator

import httpx
import pytest

from bench.procstat import children, rss_mib
from tests.harness import GroundFleet, ended, record, seq_above, submit, telemetry_seq
from tests.waiting import until

# One worker runs them all, on the module's one fleet: spread over the workers, each
# started a fleet of its own for its one or two tests. The group holds the other
# modules with a fleet of their own too, one after the other (ADR 0011).
pytestmark = [pytest.mark.integration, pytest.mark.xdist_group("module-fleets")]

MAX_MEMORY_MB = 200
MAX_CPU_S = 4
HOG = """\
chunks = []
while True:  # 1 MB more each time: a hundred gigabytes, if nothing stops it
    chunks.append("x" * 10**6 + str(len(chunks)))
"""
# One call into C that runs for days: a modular power of 100 000-bit numbers. On the
# ground's own loop it would have stalled everything (ADR 0001's stated limit).
C_SPIN = "pow(3, 2**100_000 - 1, 2**100_000 + 7)\n"
FLIGHT = """\
d = assign("drone01")
arm(d)
takeoff(d, 3*m)
move(d, forward=6*m)
land(d)
"""


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GroundFleet]:
    fcs = {d: f"sim://?lat=40.633400&lon={-8.660810 + 0.00013 * i:.6f}&alt=8.2" for i, d in enumerate(("drone01", "drone02"))}
    fleet = GroundFleet(tmp_path_factory.mktemp("limits"), fcs, {"telemetry_rate_ms": 200, "takeoff_altitude": 3.0},
                        mission={"max_memory_mb": MAX_MEMORY_MB, "max_cpu_s": MAX_CPU_S})
    yield fleet
    fleet.stop()


@pytest.mark.slow(40)
async def test_scripts_over_their_limits_fail_security_while_a_flight_finishes(fleet: GroundFleet,
                                                                                http: httpx.AsyncClient) -> None:
    assert fleet.ground.proc is not None
    ground_rss = rss_mib(fleet.ground.proc.pid)
    flight = await submit(http, FLIGHT, "flight")
    hog = await submit(http, HOG, "hog")
    c_spin = await submit(http, C_SPIN, "c-spin")
    # The example; here range() ticks (ADR 0001), so it is the CPU limit, not a stall, that ends it.
    py_spin = await submit(http, "sum(range(10**12))\n", "range-spin")

    seq = await telemetry_seq(http, "drone02")
    hog_end = await ended(http, hog, 30)
    assert (hog_end["status"], hog_end["cause"]) == ("failed", "security"), hog_end
    assert "max_memory_mb" in hog_end["message"] and "line 3" in hog_end["message"], hog_end["message"]

    for mission_id in (c_spin, py_spin):
        final = await ended(http, mission_id, 4 * MAX_CPU_S + 20)
        assert (final["status"], final["cause"]) == ("failed", "security"), final
        assert f"max_cpu_s ({MAX_CPU_S} s of CPU)" in final["message"], final["message"]
        assert final["log"][-1]["message"].startswith("Mission failed: security"), final["log"]
        # It had its CPU seconds (wall time is at least that much), and no more than the limit allows.
        assert final["end"] - final["start"] >= MAX_CPU_S * 1000, final
    # Meanwhile the ground took telemetry in all along, and answered.
    # (at least 20 samples of the 5 Hz stream arrived while the two spun for 2 x MAX_CPU_S).
    assert await telemetry_seq(http, "drone02") >= seq + 20
    flown = await ended(http, flight, 60)
    assert (flown["status"], flown["cause"]) == ("finished", "success"), flown
    # The gigabytes were never the ground's: its own memory stayed where it was.
    assert rss_mib(fleet.ground.proc.pid) < ground_rss + 100, (ground_rss, rss_mib(fleet.ground.proc.pid))


@pytest.mark.slow(30)
async def test_a_mission_stuck_in_c_code_is_cancelled_and_its_drone_released(http: httpx.AsyncClient) -> None:
    source = 'd = assign("drone02")\narm(d)\ntakeoff(d, 3*m)\n' + C_SPIN
    mission_id = await submit(http, source, "stuck")

    async def in_the_air() -> bool:
        info = (await http.get("/drone/drone02", )).json()
        return info["info"]["mission"] == mission_id and info["telem"]["position"]["rel_alt"] > 2.5 \
            and info["info"]["current_command"] is None

    await until(in_the_air, 30, "drone02 to take off for the stuck mission")
    seq = await telemetry_seq(http, "drone02")
    await until(lambda: seq_above(http, "drone02", seq + 3), 5, "telemetry while the script is stuck in C")
    response = await http.delete(f"/mission/{mission_id}")
    assert response.status_code == 200, response.text
    assert response.json()["status"] == "cancelled"
    final = await ended(http, mission_id, 5)
    assert (final["status"], final["cause"]) == ("cancelled", "user"), final
    assert "its process was killed" in final["message"], final["message"]
    info = (await http.get("/drone/drone02", params={"data": "info"})).json()["info"]
    assert info["mission"] is None and info["state"] != "unknown", info
    assert (await http.delete(f"/mission/{mission_id}")).status_code == 409
    # The drone is free for the next mission, which lands it.
    lander = await submit(http, 'd = assign("drone02")\nland(d)\n', "lander")
    assert (await ended(http, lander, 40))["status"] == "finished"
    assert (await record(http, lander))["used_drones"] == ["drone02"]


@pytest.mark.slow(15)
async def test_a_worker_killed_from_outside_is_not_called_over_its_limits(fleet: GroundFleet, http: httpx.AsyncClient) -> None:
    """The kernel's OOM killer (or an operator) sends SIGKILL; RLIMIT_CPU ends a worker
    with SIGXCPU. The mission's end says which it was."""
    assert fleet.ground.proc is not None
    ground_pid = fleet.ground.proc.pid
    mission_id = await submit(http, "sleep(600*s)\n", "waits")

    def worker() -> int | None:  # the ground's fork server's child: this mission's process
        workers = [w for server in children(ground_pid) for w in children(server)]
        return workers[0] if len(workers) == 1 else None

    os.kill(await until(worker, 20, "the mission's worker process"), signal.SIGKILL)
    final = await ended(http, mission_id, 20)
    assert (final["status"], final["cause"]) == ("failed", "unexpected"), final
    assert "killed (SIGKILL) from outside" in final["message"] and "max_cpu_s" not in final["message"], final["message"]
