"""Relaying on real packets: a drone reached only through a neighbour on the secured
mesh, and the relay plugin keeping a drone beyond range heard. A drone commanded
through a neighbour on the plain mesh, and again once back in reach, is
tests/radio/test_heard_means_commandable.py; the neighbour flying away and back is
tests/sim/test_radio_fast.py's fast-time twin."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from functools import partial
from pathlib import Path
from typing import Any

import httpx
import pytest

from dronefleet import relay_experiments as rx
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.geo import distance_m
from tests.harness import ChildProcess, GroundProcess, ended, submit
from tests.radio.emulated import (
    GROUND,
    RADIO_A,
    RADIO_B,
    REPO,
    RadioSim,
    command,
    drone,
    log_lines,
    north,
    resampled,
    state_is,
    temperature_read,
)
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.radio]


INJECT = """
import asyncio, json, sys
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.cli import secured_client

async def main(pki, name, target):
    endpoint = ["tls/127.0.0.1:7448"]
    bus = await ZenohBus.open("client", endpoint, extra=secured_client(pki, name, endpoint))
    try:
        print((await bus.query(f"drone/{target}/cmd", json.dumps(
            {"cmd": "arm", "drone_id": target, "command_id": "injected"}).encode(), timeout_s=5)).decode())
    finally:
        await bus.close()

asyncio.run(main(*sys.argv[1:]))
"""


PICK_RELAY = """
relay = assign(any_relay)
other = assign(any_drone)
print(f"relay {relay.id}; another: {other.id}")
"""


@RADIO_B  # the groups balanced on measured times (ADR 0011)
@pytest.mark.slow(40)
async def test_on_the_secured_mesh_only_a_relay_certificate_carries_a_neighbour(
        tmp_path: Path, processes: list[ChildProcess]) -> None:
    """Issue 16 on real packets, every link mutual TLS with the routers' access rules:
    droneB (105 m north, with its temperature sensor) is reachable only through droneA
    (50 m), issued `--role relay`;
    droneD (105 m south) only through droneC, a plain drone. The ground hears and
    commands droneB through droneA. droneC talks to droneD (its link reports say so) but
    does not carry it: droneD never reaches the ground. A command droneA's certificate
    injects from droneA's namespace reaches droneB and is refused `unauthenticated`.
    A mission asking for `any_relay` gets droneA; `any_drone` another."""
    from dronefleet.cli import secured_client
    from tests.harness import make_pki

    pki = make_pki(tmp_path / "pki", {"ground": "ground", "droneA": "relay", "droneB": "drone", "droneC": "drone",
                                      "droneD": "drone", "operator": "operator"})
    security = {"pki_dir": str(pki), "tls": True}
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0", scheme="tls", security=security)
    processes.append(ground)
    await ground.ready()
    a, b, c, d = north(50), north(105), north(-50), north(-105)
    # droneA may relay: its certificate (--role relay) and its About (roles) agree.
    sim = RadioSim(tmp_path, ground, [{"id": "droneA", "lat": a[0], "lon": a[1], "roles": ["survey", "relay"]}, {"id": "droneB", "lat": b[0], "lon": b[1], "sensors": ["temperature"]},
                                      {"id": "droneC", "lat": c[0], "lon": c[1]}, {"id": "droneD", "lat": d[0], "lon": d[1]}],
                   lost_link={"timeout_s": 60, "action": "continue"}, security=security)
    processes.append(sim)
    await sim.up()
    loopback = [f"tls/127.0.0.1:{ground.zenoh_port}"]
    operator = await ZenohBus.open("client", loopback, extra=secured_client(pki, "operator", loopback))
    reports: list[dict[str, Any]] = []
    try:
        operator.subscribe("drone/droneC/link", lambda sample: reports.append(json.loads(sample.payload)))
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            await until(lambda: state_is(http, "droneB", "ready"), 60, "droneB ready at the ground (through droneA)")
            await until(lambda: 'iifname "d1" oifname "g" drop' in sim.rules(), 10, "droneB-ground total loss")
            assert 'iifname "g" oifname "d1" drop' in sim.rules()
            # The on-board sensor speaks mTLS to droneB's agent, and its readings come through droneA.
            await until(lambda: temperature_read(http, "droneB"), 30, "droneB's temperature readings at the ground")
            await command(http, "droneB", cmd="arm")  # signed by the ground, carried by droneA, accepted by droneB
            await command(http, "droneB", cmd="disarm")

            injected = subprocess.run(["ip", "netns", "exec", sim.netns("droneA"), sys.executable, "-c", INJECT,
                                       str(pki), "droneA", "droneB"], capture_output=True, text=True, timeout=60,
                                      cwd=REPO)
            assert injected.returncode == 0, injected.stderr[-3000:]
            reply = json.loads(injected.stdout.splitlines()[-1])
            assert not reply["accepted"] and reply["reason"] == "unauthenticated: not signed by the ground", reply

            # droneC hears droneD well, yet the ground never learns of droneD.
            await until(lambda: any(r["peer"] == "droneD" and r["quality"] >= 0.5 for r in reports), 60,
                        "droneC's link reports on droneD")
            await until(lambda: state_is(http, "droneC", "ready"), 30, "droneC ready at the ground")
            assert (await http.get("/drone/droneD")).status_code == 404
            assert 'iifname "d3" oifname "g" drop' in sim.rules()  # droneD has no link of its own to the ground
            assert not (await drone(http, "droneB"))["telem"]["armed"]  # type: ignore[index]

            # Missions (the relay plugin) take as relays only drones the mesh lets relay.
            record = await ended(http, await submit(http, PICK_RELAY, "pick"), 30)
            log = "\n".join(line["message"] for line in record["log"])
            assert record["status"] == "finished", (record, log)
            assert "relay droneA; another: droneB" in log or "relay droneA; another: droneC" in log, log
    finally:
        await operator.close()
    assert "refused arm injected: unauthenticated: not signed by the ground" in sim.output()


RELAYED = """
enable("relay", mode="measured", good_m=35*m, lost_m=60*m, ground=[GROUND_LAT, GROUND_LON])  # the model-first planner; the default (chain) on real packets: bench/relay_real_packets.py
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=75*m, speed=8*m/s)  # past the radio's 60 m: only a relay reaches it there
sleep(5*s)
print(f"out at {distance(d.position, position(GROUND_LAT, GROUND_LON)):.0f} m")
move(d, backward=75*m, speed=8*m/s)  # sent while it is out: it must get there through the relay
land(d)
"""
RELAY_RADIO = {"good_m": 35, "lost_m": 60}  # a short radio: the same code as the default 60/100 m, in less flight


@RADIO_A
@pytest.mark.slow(65)
async def test_the_relay_plugin_keeps_a_drone_beyond_radio_range_heard_and_commanded(
        tmp_path: Path, processes: list[ChildProcess]) -> None:
    """Issue 15 on real packets: drone01 flies 75 m north, past the radio's 60 m; the
    relay plugin sends drone02 or drone03 between it and the laptop. The ground keeps
    hearing drone01's telemetry out there (the mesh routes through the relay) and the
    command that brings it back reaches it."""
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0", drone_timeout_ms=3000)
    processes.append(ground)
    await ground.ready()
    sim = RadioSim(tmp_path, ground, [{"id": "drone01", "lat": north(-4)[0], "lon": north(-4)[1]},
                                      {"id": "drone02", "lat": north(-12)[0], "lon": north(-12)[1]},
                                      {"id": "drone03", "lat": north(-20)[0], "lon": north(-20)[1]}],
                   {"radio": RELAY_RADIO}, lost_link={"timeout_s": 5, "action": "hold", "return_after_s": 60},
                   return_altitude=10)
    processes.append(sim)
    await sim.up()
    script = RELAYED.replace("GROUND_LAT", str(GROUND[0])).replace("GROUND_LON", str(GROUND[1]))
    heard_far: list[float] = []
    tracks: dict[str, dict[int, dict[str, float]]] = {}
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        for d in sim.drone_ids:
            await until(partial(state_is, http, d, "ready"), 60, f"{d} ready at the ground")
        mission_id = await submit(http, script, "relayed")

        async def watched_until_end() -> dict[str, Any] | None:
            for d in sim.drone_ids:  # every drone's track, for the separation
                seen = await drone(http, d)
                if seen is not None and seen["telem"].get("position"):
                    tracks.setdefault(d, {})[seen["telem"]["timestamp"]] = seen["telem"]["position"]
            far = await drone(http, "drone01")
            if far is not None and far["telem"].get("position"):
                p = far["telem"]["position"]
                out = distance_m(GROUND[0], GROUND[1], p["lat"], p["lon"])
                if out > RELAY_RADIO["lost_m"] + 5 and far["info"]["state"] != "unknown":
                    heard_far.append(out)
            record = (await http.get(f"/mission/{mission_id}")).json()
            return record if record["end"] is not None else None

        record = await until(watched_until_end, 240, "the relayed mission to end")
        lines = await log_lines(http, "drone01")
    log = "\n".join(line["message"] for line in record["log"])
    assert record["status"] == "finished", f"{record['status']} {record['cause']}: {record['message']}\n{log}"
    assert "relay duty" in log and re.search(r"out at [67]\d m", log), log
    assert len(heard_far) >= 5, (heard_far, "\n".join(lines[-30:]))  # heard, and not marked unknown, beyond 65 m
    separation = rx.least_separation({"drones": resampled(tracks)}, ("drone01",))
    assert 5.0 <= separation < float("inf"), separation  # a relay flew, never within min_separation (5 m)
