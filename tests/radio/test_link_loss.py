"""Links lost and found on real packets: a drone flown out of range and brought home by
its lost-link policy, and a healthy drone beside a frozen neighbour."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from dronefleet.schemas.geo import distance_m
from tests.harness import ChildProcess, GroundProcess
from tests.radio.emulated import (
    GROUND,
    RADIO_B,
    REPO,
    OnBoard,
    RadioSim,
    command,
    drone01_logged,
    field_sensor,
    index_of,
    log_lines,
    north,
    reading_of,
    state_is,
)
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.radio]


@RADIO_B
@pytest.mark.slow(55)
async def test_out_of_range_and_back(tmp_path: Path, processes: list[ChildProcess]) -> None:
    """A drone flies from 20 m towards 150 m and is brought home by its lost-link policy;
    its sensors keep feeding its agent while the ground is out of reach. Its gas sensor
    and the world's field sensor are `fleet sensor simulate` programs reading the world's
    `fields:` (the drone's in its namespace, the field sensor on its own link)."""
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0")
    processes.append(ground)
    await ground.ready()
    start, pole = north(20), north(40)
    plume = {"gas": {"co_ppm": {"background": 3, "sources": [{"lat": GROUND[0], "lon": GROUND[1], "radius": 80, "peak": 163}]}}}
    sim = RadioSim(tmp_path, ground, [{"id": "drone01", "lat": start[0], "lon": start[1], "sensors": ["temperature", "gas"]}],
                   {"fields": plume, "field_sensors": [{"id": "gas07", "type": "gas", "lat": pole[0], "lon": pole[1]}]},
                   lost_link={"timeout_s": 3, "action": "hold", "return_after_s": 6}, return_altitude=10)
    processes.append(sim)
    await sim.up()
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        await until(lambda: state_is(http, "drone01", "ready"), 60, "drone01 ready at the ground")
        onboard = OnBoard(tmp_path, sim.netns("drone01"), "drone01")  # the agent listens now
        processes.append(onboard)
        await until(lambda: onboard.messages("/sensor/temperature"), 30, "readings at the on-board listener")
        # 163 - 160 * d / 80 where each stands: 20 m (the drone) and 40 m (the pole)
        gas = await until(lambda: onboard.messages("/sensor/gas"), 30, "gas readings at the on-board listener")
        assert gas[-1]["fields"]["co_ppm"] == pytest.approx(123, abs=1.5) and gas[-1].get("value") is None, gas[-1]
        field = await until(lambda: field_sensor(http, "gas07"), 30, "field sensor gas07 at the ground")
        assert field["alive"] is True and field["types"] == ["gas"], field
        assert field["readings"][-1]["fields"]["co_ppm"] == pytest.approx(83, abs=0.5), field
        assert field["position"]["lat"] == pytest.approx(pole[0], abs=1e-6), field
        at_ground = await until(lambda: reading_of(http, "drone01", "gas"), 30, "drone01's gas reading at the ground")
        assert at_ground["fields"]["co_ppm"] == pytest.approx(123, abs=1.5), at_ground
        await command(http, "drone01", cmd="arm")
        await command(http, "drone01", cmd="takeoff", alt=10)
        await until(lambda: state_is(http, "drone01", "hold"), 60, "drone01 hovering")
        far = north(150)
        await command(http, "drone01", cmd="goto", lat=far[0], lon=far[1], speed=8)

        await until(lambda: drone01_logged(http, "Link lost"), 90, "the ground's 'Link lost'")
        await until(lambda: drone01_logged(http, "Link restored"), 120, "the ground's 'Link restored'")
        await until(lambda: state_is(http, "drone01", "ready"), 120, "drone01 home and ready")
        lines = await log_lines(http, "drone01")
        lost = index_of(lines, "Link lost")
        restored = index_of(lines, "Link restored", lost)
        # What the drone did alone reached the ground when it came back.
        assert any("Link to ground station restored: after" in line and "failsafe: hold, return" in line
                   for line in lines[lost:]), "\n".join(lines[lost:])
        assert restored > lost

    # The drone's own measurement (recorded on board, so also what never reached the
    # ground): where its quality to the ground first fell under 0.5.
    track = [(t["timestamp"], t["position"]) for t in onboard.messages("/telem") if t.get("position")]
    reports = [q for q in onboard.messages("/link") if q["peer"] == "ground"]
    first_bad = next(q for q in reports if q["quality"] < 0.5)
    at = min(track, key=lambda tp: abs(tp[0] - first_bad["timestamp"]))[1]
    dist = distance_m(GROUND[0], GROUND[1], at["lat"], at["lon"])
    assert 60 <= dist <= 100, f"quality fell under 0.5 at {dist:.0f} m: {[(q['timestamp'], q['quality']) for q in reports][-20:]}"
    assert all(q["quality"] >= 0.5 for q in reports if q["timestamp"] < first_bad["timestamp"])

    statuses = [s for s in onboard.messages("/status") if s.get("component") == "system"]
    states = [(s["state"], s.get("reason", "")) for s in statuses if s["state"] in ("link_lost", "failsafe", "link_restored")]
    # At the edge of range probes get through now and then, so the link may be
    # restored and lost again on the way; the order that matters is: lost, hold,
    # return, and restored for good once home.
    order = [next(i for i, x in enumerate(states) if x[0] == "link_lost"),
             states.index(("failsafe", "hold")), states.index(("failsafe", "return")),
             max(i for i, x in enumerate(states) if x[0] == "link_restored")]
    assert order == sorted(order), states
    assert states[-1][0] == "link_restored" and states[-1][1].endswith("failsafe: hold, return"), states
    # The outage that counts is the longest (at the edge of range a link may drop for a
    # moment first: one of 120 ms was seen, shorter than a sensor period).
    outages = [(s["timestamp"], next(b["timestamp"] for b in statuses[i:] if b["state"] == "link_restored"))
               for i, s in enumerate(statuses) if s["state"] == "link_lost"]
    lost_ms, back_ms = max(outages, key=lambda o: o[1] - o[0])
    assert back_ms - lost_ms > 3000, outages  # the hold and the return happened in it
    during = [r for r in onboard.messages("/sensor/temperature") if lost_ms < r["timestamp"] < back_ms]
    # The sensor publishes every 200 ms: the agent got its readings all through the outage.
    assert len(during) >= (back_ms - lost_ms) / 200 * 0.8, (len(during), back_ms - lost_ms)


@RADIO_B
@pytest.mark.slow(35)
async def test_a_healthy_drone_stays_heard_beside_a_frozen_neighbour(tmp_path: Path, radio_slot: None) -> None:
    """Issue 30's reproduction (bench/mesh_stall.py, one run of its frozen scenario):
    H 20 m from the laptop, R 55 m out carrying F (105 m). While R's agent is frozen
    (SIGSTOP) for 20 s, the ground hears H at 5 Hz with no gap of 1.5 s, never loses its
    token and never sees its link close. The bench's other scenario, R flying out and
    back, is in the suite as tests/radio/test_mesh_neighbour.py, where the neighbour's
    link to H turns lossy too and the ground is the real `fleet ground`.

    The bench runs as its own process, as `fleet ground` does: its ground router must
    not share this test process's Zenoh runtime with sessions earlier tests opened
    (after the secured-mesh test, in-process runs showed 3.5-4.5 s gaps that the same
    code never showed on its own)."""
    bench = subprocess.run([sys.executable, "bench/mesh_stall.py", "--runs", "1", "--scenario", "frozen",
                            "--keep", str(tmp_path)], capture_output=True, text=True, timeout=400,
                           stdin=subprocess.DEVNULL, cwd=REPO)
    lines = bench.stdout.splitlines()
    assert bench.returncode == 0, bench.stdout[-3000:] + bench.stderr[-3000:]
    assert lines[-1].startswith("frozen: 1/1 runs kept H heard"), lines
