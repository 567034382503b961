"""The agent contract (SPEC §2–§3) over real Zenoh: a router in this process,
`fleet agent` as a subprocess, commands as real queries.

`flight_controller` (tests/agent/conftest.py) is parametrized per adapter; every test here
runs unchanged against each of them.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Callable
from pathlib import Path

import pytest

from dronefleet.schemas.geo import angle_diff_deg, bearing_deg, destination, distance_m
from tests.harness import AgentProcess, Operator, at
from tests.waiting import until

pytestmark = pytest.mark.integration

SPEC_TELEMETRY_FIELDS = {
    "drone_id", "timestamp", "seq", "armed", "battery", "flight_mode", "gps_info", "heading",
    "health_failures", "home", "landed_state", "position", "velocity", "speed",
}
NESTED = {
    "battery": {"remaining_percent", "voltage"},
    "gps_info": {"satellites", "fix_type"},
    "home": {"lat", "lon", "alt"},
    "position": {"lat", "lon", "alt", "rel_alt"},
    "velocity": {"north", "east", "down"},
}


@pytest.mark.slow(50)
async def test_flight_contract(
    agents: Callable[..., AgentProcess], operator: Callable[[str], Operator], flight_controller: str
) -> None:
    agents("drone01", fc=flight_controller, return_altitude=10, acceptance_radius=0.5, max_speed=10)
    op = operator("drone01")

    # Telemetry carries every SPEC field, at the configured 100 ms, once the flight
    # controller has sent each (until then that field is null: MAVSDK's home, say, can
    # come a second after the first position on a loaded machine). The period is the
    # median interval: a process stalled by a loaded machine skips the periods it missed
    # (never a burst of stale samples: no interval much under half a period), and one
    # long interval does not move the median.
    await op.next_telemetry(lambda t: all(getattr(t, key) is not None for key in NESTED), timeout_s=30,
                            what="telemetry with every field known")
    for _ in range(21):
        await op.next_telemetry(timeout_s=5)
    raw = json.loads(op.raw_telem[-1])
    assert set(raw) == SPEC_TELEMETRY_FIELDS
    for key, fields in NESTED.items():
        assert set(raw[key]) == fields, key
    stamps = [t.timestamp for t in op.telem.items[-21:]]
    intervals = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    assert 80 <= statistics.median(intervals) <= 130 and min(intervals) >= 40, intervals
    assert [t.seq for t in op.telem.items[-21:]] == list(range(op.telem.items[-21].seq, op.telem.items[-21].seq + 21))
    home = at(op.last)

    # Takeoff is refused while disarmed, with the reason.
    reply = await op.send("takeoff", alt=5)
    assert not reply.accepted and reply.reason == "disarmed"
    await op.expect(reply.command_id, "failure", 30)

    await op.expect(await op.accepted("arm"), "success", 30)
    takeoff = await op.accepted("takeoff", alt=5)
    assert (await op.expect(takeoff, "start", 10)).altitude == 5
    await op.expect(takeoff, "finish", 30)
    t = await op.next_telemetry()
    assert at(t).rel_alt == pytest.approx(5, abs=0.5)

    # Goto 30 m north, yaw null (face the target), no alt (keep altitude).
    alt_before = at(t).alt
    lat, lon = destination(at(t).lat, at(t).lon, 30, 0)
    goto = await op.accepted("goto", lat=lat, lon=lon, yaw=None)
    start = await op.expect(goto, "start", 30)
    assert start.coords is not None
    assert (start.coords.lat, start.coords.lon) == pytest.approx((lat, lon))
    assert start.coords.alt == pytest.approx(alt_before, abs=0.3)
    await op.expect(goto, "finish", 40)
    t = await op.next_telemetry()
    assert distance_m(at(t).lat, at(t).lon, lat, lon) <= 0.5 + 0.5
    assert abs(angle_diff_deg(t.heading, 0)) < 3
    assert at(t).alt == pytest.approx(alt_before, abs=0.5)

    # Turn 90° clockwise.
    turn = await op.accepted("turn", deg=90)
    await op.expect(turn, "finish", 30)
    t = await op.next_telemetry()
    assert abs(angle_diff_deg(t.heading, 90)) < 3

    # Move 10 m to the right of the heading (east-facing: right is south).
    before = at(t)
    move = await op.accepted("move", x=10)
    await op.expect(move, "finish", 30)
    t = await op.next_telemetry()
    assert distance_m(before.lat, before.lon, at(t).lat, at(t).lon) == pytest.approx(10, abs=1.0)
    assert abs(angle_diff_deg(bearing_deg(before.lat, before.lon, at(t).lat, at(t).lon), 180)) < 5

    # A goto far west faces west (yaw null), and a cancel stops it.
    lat, lon = destination(at(t).lat, at(t).lon, 300, 270)
    far = await op.accepted("goto", lat=lat, lon=lon, yaw=None)
    await op.expect(far, "start", 30)
    await op.next_telemetry(lambda t: abs(angle_diff_deg(t.heading, 270)) < 3 and t.speed > 1, 20, "flying west")
    cancel = await op.accepted("cancel")
    await op.expect(far, "cancel", 30)
    await op.expect(cancel, "success", 30)
    await op.next_telemetry(lambda t: t.speed < 0.1, 10, "holding after cancel")

    # Return to launch: climb to at least 10 m, fly home, land, disarm by itself.
    ret = await op.accepted("return")
    assert (await op.expect(ret, "start", 10)).altitude == 10
    landed = await op.expect(ret, "finish", 90)
    # Telemetry sampled after the finish (on a busy machine one sampled just before it
    # can arrive after it: seen once, "landing").
    t = await op.next_telemetry(lambda t: t.timestamp >= landed.timestamp, 10, "telemetry taken after the finish")
    assert t.landed_state == "on_ground"
    assert distance_m(at(t).lat, at(t).lon, home.lat, home.lon) < 1.0
    await op.system("disarm", 30)

    # Two gotos during a takeoff are queued; only the last one flies.
    await op.expect(await op.accepted("arm"), "success", 30)
    takeoff = await op.accepted("takeoff", alt=4)
    here = at(op.last)
    first = await op.accepted("goto", **dict(zip(("lat", "lon"), destination(here.lat, here.lon, 15, 90), strict=True)))
    lat, lon = destination(here.lat, here.lon, 15, 0)
    last = await op.accepted("goto", lat=lat, lon=lon)
    await op.expect(first, "queued", 30)
    await op.expect(last, "queued", 30)
    await op.expect(first, "cancel", 30)
    await op.expect(takeoff, "finish", 30)
    await op.expect(last, "start", 30)
    await op.expect(last, "finish", 30)
    assert op.statuses_of(first) == ["queued", "cancel"]
    t = await op.next_telemetry()
    assert distance_m(at(t).lat, at(t).lon, lat, lon) < 1.0

    # A goto is refused while landing; the landing finishes on the ground and the
    # drone disarms itself.
    land = await op.accepted("land")
    await op.expect(land, "start", 30)
    reply = await op.send("goto", lat=here.lat, lon=here.lon)
    assert not reply.accepted and reply.reason == "landing"
    await op.expect(land, "finish", 40)
    assert (await op.next_telemetry()).landed_state == "on_ground"
    await op.system("disarm", 30)
    assert not (await op.next_telemetry(lambda t: not t.armed, 5)).armed


SPAWN = (40.633490, -8.660815)  # where `--fc sim` and `fleet sim` put drone01


def _square(half_m: float) -> list[list[float]]:
    n, s = destination(*SPAWN, half_m, 0)[0], destination(*SPAWN, half_m, 180)[0]
    e, w = destination(*SPAWN, half_m, 90)[1], destination(*SPAWN, half_m, 270)[1]
    return [[n, w], [n, e], [s, e], [s, w]]


@pytest.mark.slow(40)
async def test_the_agent_keeps_its_geofence_whatever_path_a_command_takes(
    agents: Callable[..., AgentProcess], operator: Callable[[str], Operator], flight_controller: str, tmp_path: Path,
) -> None:
    """SPEC §11 at the agent, with no ground in the way: this operator queries
    drone/drone01/cmd directly. Flights out of the fence or over its ceiling are
    refused (reason `geofence`), return always goes through, the fence is uploaded to
    the flight controller, and a drone pushed outside (an offboard velocity, which
    names no target to check) is turned home by the agent's failsafe."""
    agents("drone01", fc=flight_controller, return_altitude=10, geofence={"polygon": _square(30), "max_alt_m": 20})
    op = operator("drone01")
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    log = tmp_path / "drone01.log"
    await until(lambda: "geofence of 4 vertices uploaded" in log.read_text(), 30, "the fence uploaded to the autopilot")

    high = await op.send("takeoff", alt=25)  # over max_alt_m 20 above home
    assert not high.accepted and high.reason is not None and high.reason.startswith("geofence: "), high
    await op.expect(await op.accepted("arm"), "success", 30)
    takeoff = await op.accepted("takeoff", alt=5)
    await op.expect(takeoff, "finish", 30)
    here = at(await op.next_telemetry())
    far = destination(here.lat, here.lon, 45, 0)
    out = await op.send("goto", lat=far[0], lon=far[1])
    assert not out.accepted and out.reason is not None and "outside the fence" in out.reason, out
    ahead = await op.send("move", y=40)  # forward (north), 40 m: past the edge at 30 m
    assert not ahead.accepted and ahead.reason is not None and ahead.reason.startswith("geofence: "), ahead
    inside = destination(here.lat, here.lon, 20, 0)
    await op.expect(await op.accepted("goto", lat=inside[0], lon=inside[1]), "finish", 30)

    await op.accepted("velocity_ned", north=4.0, east=0.0, down=0.0)  # out through the north edge
    failsafe = await op.system("failsafe", 30)
    assert failsafe.reason is not None and failsafe.reason.startswith("return: outside the geofence"), failsafe
    landed = await op.next_telemetry(lambda t: t.landed_state == "on_ground" and not t.armed, 90, "home, landed")
    assert distance_m(at(landed).lat, at(landed).lon, *SPAWN) < 2.0
