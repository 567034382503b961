"""The field network on real packets (SPEC §8): `fleet sim --agents --radio` puts each
drone's agent and sensor in its own network namespace on the emulated radio, a real
`fleet ground` listens in this namespace (the laptop), and the loss between nodes
follows the simulated distances. Needs CAP_NET_ADMIN: in CI (root) a missing
capability fails these tests instead of skipping them.
"""

from __future__ import annotations

import fcntl
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from dronefleet import relay_experiments as rx
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.fleet_sim import CHILDREN_STOP_S
from dronefleet.sim.radio_net import has_net_admin, host_lock, leftovers, list_netns
from tests.harness import ChildProcess, GroundProcess, ended, fleet_command, stop_all, submit
from tests.helpers import RADIO_SLOTS, free_port, free_udp_base, signal_and_wait, until

pytestmark = [pytest.mark.integration, pytest.mark.radio]
GROUND = (40.633490, -8.660815)
FIELD_ALT = 8.2
SIM_STOP_S = CHILDREN_STOP_S + 10  # `fleet sim --radio` gives its agents CHILDREN_STOP_S, then takes the radio down
SLOT_WAIT_S = 240


@pytest.fixture(autouse=True)
def net_admin() -> None:
    if not has_net_admin():
        if os.environ.get("CI") or os.geteuid() == 0:
            # As root (CI runs so) a missing capability is a broken machine, not a reason to skip.
            pytest.fail("the emulated-radio tests need CAP_NET_ADMIN, which this root lacks "
                        "(a container without --cap-add NET_ADMIN?)")
        pytest.skip("needs CAP_NET_ADMIN (run as root)")


def north(metres: float) -> tuple[float, float]:
    return destination(GROUND[0], GROUND[1], metres, 0.0)


def fleet_resources(pid: int) -> list[str]:
    """What a radio run of `pid` has on this machine: namespaces, the laptop link."""
    links = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True).stdout
    return [ns for ns in list_netns() if ns.startswith(f"fleet-{pid}-")] + (
        [f"fl{pid}g"] if f" fl{pid}g" in links or f": fl{pid}g@" in links else []
    )


class RadioSim(ChildProcess):
    """`fleet sim WORLD --agents --radio` with its world and agent config written here."""

    name = "fleet sim --radio"

    def __init__(self, tmp: Path, ground: GroundProcess, drones: list[dict[str, Any]], world_keys: dict[str, Any] | None = None,
                 **agent: Any) -> None:
        world = tmp / "world.yml"
        world.write_text(yaml.safe_dump({
            "origin": {"lat": GROUND[0], "lon": GROUND[1], "alt": FIELD_ALT},
            "ground_station": {"lat": GROUND[0], "lon": GROUND[1]},
            "drones": drones,
            "heat_sources": [{"lat": GROUND[0], "lon": GROUND[1], "radius": 300, "temp": 60}],
            **(world_keys or {}),
        }))
        cfg = tmp / "agent.yml"
        cfg.write_text(yaml.safe_dump({"telemetry_rate_ms": 200, "probe_period_ms": 500, "probe_window": 6, "max_speed": 10, **agent}))
        self.drone_ids = [d["id"] for d in drones]
        super().__init__(fleet_command(
            "-v", "sim", str(world), "--agents", "--radio", "--agent-config", str(cfg),
            "--ground-port", str(ground.zenoh_port), "--base-port", str(free_udp_base(2) + 1),
        ), tmp / "sim.log")

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = SIM_STOP_S) -> int | None:
        return super().stop(sig, timeout_s)

    def netns(self, drone_id: str) -> str:
        return f"fleet-{self.pid}-{drone_id}"

    async def up(self) -> None:
        await until(lambda: self._alive() and all(self.netns(d) in list_netns() for d in self.drone_ids),
                    30, "the radio namespaces")

    def _alive(self) -> bool:
        assert self.proc is not None and self.proc.poll() is None, f"fleet sim exited:\n{self.output()[-3000:]}"
        return True

    def rules(self) -> str:
        return subprocess.run(["ip", "netns", "exec", f"fleet-{self.pid}-air", "nft", "list", "table", "bridge", "fleet_radio"],
                              capture_output=True, text=True).stdout


class OnBoard(ChildProcess):
    """`fleet sub` inside a drone's namespace, connected to that drone's agent only."""

    name = "on-board listener"

    def __init__(self, tmp: Path, netns: str, drone_id: str) -> None:
        super().__init__(["ip", "netns", "exec", netns, *fleet_command(
            "sub", f"drone/{drone_id}/**", "--connect", "tcp/127.0.0.1:7448")], tmp / f"onboard-{drone_id}.log")

    def messages(self, kind: str) -> list[dict[str, Any]]:
        out = []
        for line in self.output().splitlines():
            key, _, body = line.partition(" ")
            if key.endswith(kind) and body.startswith("{"):
                out.append(json.loads(body))
        return out


# The radio tests in two groups, one per radio slot (RADIO_SLOTS): `--dist loadgroup` runs
# each group on one worker, one test after another, so no radio test waits for a slot on
# a worker that could be running something else (one waited 42-75 s a run). Balanced on
# their measured times with six workers: about 205 s (a) and 225 s (b).
RADIO_A = pytest.mark.xdist_group("radio-a")
RADIO_B = pytest.mark.xdist_group("radio-b")


@pytest.fixture
def radio_slot() -> Iterator[None]:
    """One of RADIO_SLOTS host-wide slots (a lock file each), held while the test runs."""
    deadline = time.monotonic() + SLOT_WAIT_S
    while True:
        for i in range(RADIO_SLOTS):
            fd = os.open(f"/tmp/fleet-test-radio-slot-{i}.lock", os.O_CREAT | os.O_RDWR, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            try:
                yield
            finally:
                os.close(fd)  # releases the lock
            return
        if time.monotonic() > deadline:
            pytest.fail(f"no radio slot free after {SLOT_WAIT_S} s")
        time.sleep(0.2)  # polling a lock held by another test's run


@pytest.fixture
def processes(tmp_path: Path, radio_slot: None) -> Iterator[list[ChildProcess]]:
    """Everything a test starts, stopped in reverse; then nothing of the run may remain."""
    started: list[ChildProcess] = []
    yield started
    sims = [p for p in started if isinstance(p, RadioSim)]
    stop_all(reversed(started))  # all of them, even when one is slow to stop
    for sim in sims:
        assert fleet_resources(sim.pid) == [], f"left behind: {fleet_resources(sim.pid)}"


async def drone(http: httpx.AsyncClient, drone_id: str) -> dict[str, Any] | None:
    r = await http.get(f"/drone/{drone_id}")
    return r.json() if r.status_code == 200 else None


async def command(http: httpx.AsyncClient, drone_id: str, **body: Any) -> None:
    r = await http.post(f"/drone/{drone_id}/cmd", json=body)
    assert r.status_code == 200, r.text


async def log_lines(http: httpx.AsyncClient, drone_id: str) -> list[str]:
    return (await http.get("/drone/logs", params={"drone_id": drone_id})).text.splitlines()


async def state_is(http: httpx.AsyncClient, drone_id: str, state: str) -> bool:
    d = await drone(http, drone_id)
    return d is not None and d["info"]["state"] == state


def index_of(lines: list[str], text: str, start: int = 0) -> int:
    for i in range(start, len(lines)):
        if text in lines[i]:
            return i
    raise AssertionError(f"no line with {text!r} after line {start}:\n" + "\n".join(lines[-40:]))


@RADIO_B
@pytest.mark.slow(70)
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
        field = await until(lambda: _field_sensor(http, "gas07"), 30, "field sensor gas07 at the ground")
        assert field["alive"] is True and field["types"] == ["gas"], field
        assert field["readings"][-1]["fields"]["co_ppm"] == pytest.approx(83, abs=0.5), field
        assert field["position"]["lat"] == pytest.approx(pole[0], abs=1e-6), field
        at_ground = await until(lambda: _reading(http, "drone01", "gas"), 30, "drone01's gas reading at the ground")
        assert at_ground["fields"]["co_ppm"] == pytest.approx(123, abs=1.5), at_ground
        await command(http, "drone01", cmd="arm")
        await command(http, "drone01", cmd="takeoff", alt=10)
        await until(lambda: state_is(http, "drone01", "hold"), 60, "drone01 hovering")
        far = north(150)
        await command(http, "drone01", cmd="goto", lat=far[0], lon=far[1], speed=4)

        await until(lambda: _has(http, "Link lost"), 90, "the ground's 'Link lost'")
        await until(lambda: _has(http, "Link restored"), 120, "the ground's 'Link restored'")
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
    lost_ms = next(s["timestamp"] for s in statuses if s["state"] == "link_lost")
    back_ms = next(s["timestamp"] for s in statuses if s["state"] == "link_restored" and s["timestamp"] > lost_ms)
    during = [r for r in onboard.messages("/sensor/temperature") if lost_ms < r["timestamp"] < back_ms]
    # The sensor publishes every 200 ms: the agent got its readings all through the outage.
    assert len(during) >= (back_ms - lost_ms) / 200 * 0.8, (len(during), back_ms - lost_ms)


async def _field_sensor(http: httpx.AsyncClient, sensor_id: str) -> dict[str, Any] | None:
    r = await http.get(f"/sensor/{sensor_id}")
    return r.json() if r.status_code == 200 and r.json()["readings"] else None


async def _reading(http: httpx.AsyncClient, drone_id: str, kind: str) -> dict[str, Any] | None:
    view = await drone(http, drone_id)
    return next((r for r in (view or {}).get("sensors") or [] if r["type"] == kind), None)


async def _has(http: httpx.AsyncClient, text: str) -> bool:
    return any(text in line for line in await log_lines(http, "drone01"))


@RADIO_A
@pytest.mark.slow(20)
async def test_relay_through_a_neighbour(tmp_path: Path, processes: list[ChildProcess]) -> None:
    """Ground, A at 50 m, B at 105 m: B is reachable only through A; A leaves, B is
    lost; A comes back, B is reachable again within 5 s."""
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0")
    processes.append(ground)
    await ground.ready()
    a, b = north(50), north(105)
    # droneA may relay: its certificate (--role relay) and its About (roles) agree.
    sim = RadioSim(tmp_path, ground, [{"id": "droneA", "lat": a[0], "lon": a[1], "roles": ["survey", "relay"]}, {"id": "droneB", "lat": b[0], "lon": b[1]}],
                   lost_link={"timeout_s": 60, "action": "continue"})
    processes.append(sim)
    await sim.up()
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        await until(lambda: state_is(http, "droneB", "ready"), 60, "droneB ready at the ground (through droneA)")
        await until(lambda: state_is(http, "droneA", "ready"), 60, "droneA ready (its autopilot's health known)")
        # Only through A: B's packets to and from the ground are all dropped.
        await until(lambda: 'iifname "d1" oifname "g" drop' in sim.rules(), 10, "B-ground total loss")
        assert 'iifname "g" oifname "d1" drop' in sim.rules()
        await command(http, "droneB", cmd="arm")  # accepted: the agent's reply came back through A
        await command(http, "droneB", cmd="disarm")

        away = destination(GROUND[0], GROUND[1], 55, 180.0)  # 55 m south: 155 m from B
        await command(http, "droneA", cmd="arm")
        await command(http, "droneA", cmd="takeoff", alt=5)
        await until(lambda: state_is(http, "droneA", "hold"), 60, "droneA hovering")
        await command(http, "droneA", cmd="goto", lat=away[0], lon=away[1], speed=10)
        await until(lambda: state_is(http, "droneB", "unknown"), 60, "droneB unreachable once droneA left")
        await command(http, "droneA", cmd="goto", lat=a[0], lon=a[1], speed=10)

        async def a_back() -> bool:  # within good range (60 m) of B again: no loss between them
            info = await drone(http, "droneA")
            assert info is not None
            pos = info["telem"]["position"]
            return distance_m(b[0], b[1], pos["lat"], pos["lon"]) < 60

        await until(a_back, 60, "droneA back within range of droneB")
        # How soon is bench/mesh.py's failover figure; here a liveness deadline.
        await until(lambda: _reachable(http, "droneB"), 30, "droneB reachable again")


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


@RADIO_B
@pytest.mark.slow(60)
async def test_a_healthy_drone_stays_heard_beside_a_lossy_or_frozen_neighbour(tmp_path: Path, radio_slot: None) -> None:
    """Issue 30's reproduction (bench/mesh_stall.py, one run of each scenario): H 20 m
    from the laptop, R 55 m out carrying F (105 m). While R flies out to 92 m and back,
    and while R's agent is frozen for 20 s, the ground hears H at 5 Hz with no gap of
    1.5 s, never loses its token and never sees its link close.

    The bench runs as its own process, as `fleet ground` does: its ground router must
    not share this test process's Zenoh runtime with sessions earlier tests opened
    (after the secured-mesh test, in-process runs showed 3.5-4.5 s gaps that the same
    code never showed on its own)."""
    bench = subprocess.run([sys.executable, "bench/mesh_stall.py", "--runs", "1", "--scenario", "both",
                            "--keep", str(tmp_path)], capture_output=True, text=True, timeout=400,
                           stdin=subprocess.DEVNULL, cwd=Path(__file__).parent.parent)
    lines = bench.stdout.splitlines()
    assert bench.returncode == 0, bench.stdout[-3000:] + bench.stderr[-3000:]
    assert [line.split(":")[0] for line in lines[-2:]] == ["lossy", "frozen"], lines
    assert all(line.split(": ", 1)[1].startswith("1/1 runs kept H heard") for line in lines[-2:]), lines


@RADIO_A
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
            await until(lambda: _temperature(http, "droneB"), 30, "droneB's temperature readings at the ground")
            await command(http, "droneB", cmd="arm")  # signed by the ground, carried by droneA, accepted by droneB
            await command(http, "droneB", cmd="disarm")

            injected = subprocess.run(["ip", "netns", "exec", sim.netns("droneA"), sys.executable, "-c", INJECT,
                                       str(pki), "droneA", "droneB"], capture_output=True, text=True, timeout=60,
                                      cwd=Path(__file__).parent.parent)
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


async def _temperature(http: httpx.AsyncClient, drone_id: str) -> bool:
    view = (await http.get(f"/drone/{drone_id}", params={"data": "sensors"})).json()
    return any(r["type"] == "temperature" for r in view.get("sensors") or [])


SURVEY_ALONE = """
d = assign("DRONE")
arm(d)
r = push(d, [step.takeoff(10*m), step.move(DIRECTION=140*m, speed=8*m/s), step.wait(3*s), step.move(BACK=140*m, speed=8*m/s)],
         on_link_loss=POLICY, timeout=180*s)
print(f"bundle {r.state} at step {r.step + 1}: {r.ended_by}; history {[(e.step, e.state) for e in r.history]}")
assert [e.state for e in r.history] == HISTORY, r.history  # every event, also those sent out of reach
home(d)
"""


@RADIO_A
@pytest.mark.slow(60)
async def test_survey_bundles_beyond_radio_range_continue_alone_or_return(tmp_path: Path, processes: list[ChildProcess]) -> None:
    """Issue 14 on real packets: two drones take survey bundles past the radio's 100 m,
    drone01 north with on_link_loss=continue, drone02 south with return. The ground
    loses drone01, which finishes alone; back in range the mission gets its whole
    history and the ground's log catches up. drone02 gives up and comes home."""
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0", drone_timeout_ms=3000)
    processes.append(ground)
    await ground.ready()
    sim = RadioSim(tmp_path, ground, [{"id": "drone01", "lat": north(4)[0], "lon": north(4)[1]},
                                      {"id": "drone02", "lat": north(-4)[0], "lon": north(-4)[1]}],
                   lost_link={"timeout_s": 3, "action": "hold", "return_after_s": 60}, return_altitude=10)
    processes.append(sim)
    await sim.up()
    cases = {
        "drone01": ("forward", "backward", "continue", ["start", "finish"] * 4 + ["done"]),
        "drone02": ("backward", "forward", "return", ["start", "finish", "start", "guard"]),
    }
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        for d in cases:
            await until(partial(state_is, http, d, "ready"), 60, f"{d} ready at the ground")
        missions = {}
        for d, (direction, back, policy, history) in cases.items():
            script = (SURVEY_ALONE.replace("DRONE", d).replace("DIRECTION", direction).replace("BACK", back)
                      .replace("POLICY", repr(policy)).replace("HISTORY", repr(history)))
            missions[d] = await submit(http, script, f"survey {policy}")
        records = {d: await ended(http, m, 240) for d, m in missions.items()}
        log_one, log_two = ("\n".join(line["message"] for line in records[d]["log"]) for d in cases)
        for d in cases:
            assert records[d]["status"] == "finished", f"{d}: {records[d]}"
        one, two = await log_lines(http, "drone01"), await log_lines(http, "drone02")
        try:
            await until(lambda: state_is(http, "drone02", "ready"), 60, "drone02 landed and ready")
        except AssertionError:
            now = await drone(http, "drone02")
            raise AssertionError(f"drone02 not ready: {now}\nmission: {log_two}\n" + "\n".join((await log_lines(http, "drone02"))[-25:])) from None
        home_two = (await drone(http, "drone02"))["telem"]["position"]  # type: ignore[index]

    # drone01 flew on alone: the ground lost it, the mission waited, then caught up.
    lost = index_of(one, "Link lost")
    caught = index_of(one, "caught up on", lost)
    assert any("Bundle b-" in line and "done (4 steps)" in line for line in one[caught:]), "\n".join(one[lost:])
    assert "link lost while it runs bundle" in log_one and "link restored, the mission goes on" in log_one, log_one
    assert "bundle done at step 4" in log_one, log_one
    # drone02 turned home when its probes to the ground went unanswered, and the mission
    # still got its record. Whether the ground also dropped its (lossy, still open) link
    # for a while depends on the 4 s lease against the radio: not asserted (ADR 0003).
    assert "bundle ended at step 2: link_lost" in log_two, log_two
    index_of(two, "ended by link lost (on_link_loss=return) at step 2")
    assert distance_m(*north(-4), home_two["lat"], home_two["lon"]) < 5, home_two


RELAYED = """
enable("relay", mode="measured", ground=[GROUND_LAT, GROUND_LON])  # the model-first planner; the default (chain) on real packets: bench/relay_real_packets.py
d = assign("drone01")
arm(d)
takeoff(d, 10*m)
move(d, forward=125*m, speed=5*m/s)  # past the radio's 100 m: only a relay reaches it there
sleep(15*s)
print(f"out at {distance(d.position, position(GROUND_LAT, GROUND_LON)):.0f} m")
move(d, backward=125*m, speed=5*m/s)  # sent while it is out: it must get there through the relay
land(d)
"""


@RADIO_A
@pytest.mark.slow(90)
async def test_the_relay_plugin_keeps_a_drone_beyond_radio_range_heard_and_commanded(
        tmp_path: Path, processes: list[ChildProcess]) -> None:
    """Issue 15 on real packets: drone01 flies 125 m north, past the radio's 100 m; the
    relay plugin sends drone02 or drone03 between it and the laptop. The ground keeps
    hearing drone01's telemetry out there (the mesh routes through the relay) and the
    command that brings it back reaches it."""
    ground = GroundProcess(tmp_path, zenoh_host="0.0.0.0", drone_timeout_ms=3000)
    processes.append(ground)
    await ground.ready()
    sim = RadioSim(tmp_path, ground, [{"id": "drone01", "lat": north(-4)[0], "lon": north(-4)[1]},
                                      {"id": "drone02", "lat": north(-12)[0], "lon": north(-12)[1]},
                                      {"id": "drone03", "lat": north(-20)[0], "lon": north(-20)[1]}],
                   lost_link={"timeout_s": 5, "action": "hold", "return_after_s": 60}, return_altitude=10)
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
                if out > 105 and far["info"]["state"] != "unknown":
                    heard_far.append(out)
            record = (await http.get(f"/mission/{mission_id}")).json()
            return record if record["end"] is not None else None

        record = await until(watched_until_end, 240, "the relayed mission to end")
        lines = await log_lines(http, "drone01")
    log = "\n".join(line["message"] for line in record["log"])
    assert record["status"] == "finished", f"{record['status']} {record['cause']}: {record['message']}\n{log}"
    assert "relay duty" in log and re.search(r"out at 1[12]\d m", log), log
    assert len(heard_far) >= 5, (heard_far, "\n".join(lines[-30:]))  # heard, and not marked unknown, beyond 105 m
    separation = rx.least_separation({"drones": resampled(tracks)}, ("drone01",))
    assert 5.0 <= separation < float("inf"), separation  # a relay flew, never within min_separation (5 m)


def resampled(tracks: dict[str, dict[int, dict[str, float]]], every_s: float = 0.5,
              longest_gap_s: float = 2.5) -> dict[str, dict[str, list[dict[str, float]]]]:
    """The drones' telemetry, as the API showed it, on one time grid (each drone's
    samples come at their own times): interpolated between samples at most
    `longest_gap_s` apart, in the shape fleet.relay_experiments reads."""
    start = min(min(t) for t in tracks.values()) / 1000
    end = max(max(t) for t in tracks.values()) / 1000
    grid = [start + i * every_s for i in range(int((end - start) / every_s) + 1)]
    out: dict[str, dict[str, list[dict[str, float]]]] = {}
    for drone_id, samples in tracks.items():
        times = sorted(samples)
        points = []
        for t in grid:
            for a, b in itertools.pairwise(times):
                if a / 1000 <= t <= b / 1000 and (b - a) / 1000 <= longest_gap_s:
                    f = (t - a / 1000) / max((b - a) / 1000, 1e-9)
                    pa, pb = samples[a], samples[b]
                    points.append({"t_s": round(t, 3), **{k: pa[k] + f * (pb[k] - pa[k]) for k in ("lat", "lon", "rel_alt")}})
                    break
        out[drone_id] = {"samples": points}
    return out


async def _reachable(http: httpx.AsyncClient, drone_id: str) -> bool:
    d = await drone(http, drone_id)
    return d is not None and d["info"]["state"] != "unknown"


@RADIO_B
def test_a_killed_launcher_leaves_nothing_after_the_next_start(tmp_path: Path, radio_slot: None) -> None:
    """SIGKILL `fleet sim --radio`: its namespaces stay (and its agents die with it);
    the next radio run removes them before it builds its own."""
    world = tmp_path / "world.yml"
    world.write_text(yaml.safe_dump({"drones": [{"id": "drone01"}]}))
    killed = subprocess.Popen(fleet_command("sim", str(world), "--radio", "--base-port", str(free_udp_base(2) + 1)),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_sync(lambda: f"fleet-{killed.pid}-air" in list_netns(), 30, "the first run's namespaces")
    finally:
        with host_lock():  # no radio run of a parallel test cleans up before we look
            killed.kill()
            killed.wait()
            namespaces, _ = leftovers()
    assert f"fleet-{killed.pid}-air" in namespaces
    second = subprocess.Popen(fleet_command("sim", str(world), "--radio", "--base-port", str(free_udp_base(2) + 1)),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_sync(lambda: f"fleet-{second.pid}-air" in list_netns(), 30, "the second run's namespaces")
        assert fleet_resources(killed.pid) == []
    finally:
        signal_and_wait(second, signal.SIGINT, SIM_STOP_S, "the second fleet sim --radio")
    assert fleet_resources(second.pid) == []


@RADIO_A
def test_radio_runs_started_together_get_their_own_subnets(radio_slot: None) -> None:
    """Parallel radio runs (these tests under xdist, two operators on one laptop) must
    not pick the same /24: the pick holds a lock until the address is taken."""
    from concurrent.futures import ThreadPoolExecutor

    from dronefleet.sim.radio import RadioModel
    from dronefleet.sim.radio_net import RadioNet

    nets = [RadioNet(["d1"], RadioModel(), run=pid) for pid in (os.getpid(), os.getppid())]
    try:
        with ThreadPoolExecutor(2) as pool:
            list(pool.map(RadioNet.up, nets))
        assert nets[0].subnet != nets[1].subnet, [n.subnet for n in nets]
    finally:
        for net in nets:
            net.close()
    assert not [ns for ns in list_netns() if ns.startswith((f"fleet-{os.getpid()}-", f"fleet-{os.getppid()}-"))]


def test_without_net_admin_the_radio_says_so_and_exits_2(tmp_path: Path) -> None:
    world = tmp_path / "world.yml"
    world.write_text(yaml.safe_dump({"drones": [{"id": "drone01"}]}))
    # Drop CAP_NET_ADMIN from the child's bounding and effective sets (setpriv, util-linux).
    result = subprocess.run(["setpriv", "--inh-caps=-all", "--bounding-set=-net_admin", "--",
                             *fleet_command("sim", str(world), "--radio")],
                            capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL)
    assert result.returncode == 2, result
    assert "CAP_NET_ADMIN" in result.stderr


def test_as_root_without_net_admin_the_radio_tests_fail_rather_than_skip(tmp_path: Path) -> None:
    """A root without CAP_NET_ADMIN (a default container) must not pass the suite by
    skipping every radio test (issue 31): one radio test run so fails, and says why."""
    if os.geteuid() != 0:
        pytest.fail("run as root, as CI does")
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "PYTEST_XDIST_WORKER", "PYTEST_ADDOPTS")}
    result = subprocess.run(
        ["setpriv", "--inh-caps=-all", "--bounding-set=-net_admin", "--", sys.executable, "-m", "pytest", "-q",
         "-p", "no:cacheprovider", "-p", "no:randomly", f"{__file__}::test_radio_runs_started_together_get_their_own_subnets"],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, env=env, cwd=tmp_path)
    assert result.returncode == 1, result.stdout[-3000:]
    assert "1 error" in result.stdout and "skipped" not in result.stdout, result.stdout[-3000:]  # its fixture fails
    assert "CAP_NET_ADMIN, which this root lacks" in result.stdout


def _wait_sync(predicate: Any, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.1)


@RADIO_B
@pytest.mark.slow(80)
@pytest.mark.timeout(480)
def test_the_demo_on_the_radio_traces_the_fire_and_leaves_nothing(tmp_path: Path, radio_slot: None) -> None:
    """`fleet demo --radio`: the fire world with the laptop beside the fire (every point
    of the trace in good range); each agent and sensor in its namespace."""
    from tests.test_demo import run_demo

    world = tmp_path / "near.yml"
    world.write_text(yaml.safe_dump({
        "origin": {"lat": 40.633490, "lon": -8.660815, "alt": 8.2},
        "ground_station": {"lat": 40.633849, "lon": -8.660637},
        "drones": [{"id": "drone01", "lat": 40.633490, "lon": -8.660815, "sensors": ["temperature"]},
                   {"id": "drone02", "lat": 40.633490, "lon": -8.660756}],
        "heat_sources": [{"lat": 40.633849, "lon": -8.660637, "radius": 50, "temp": 60}],
    }))
    out = tmp_path / "demo-out"
    code, stdout, stderr, elapsed = run_demo(
        "--radio", "--until-done", "--world", str(world), "--port", str(free_port()), "--http-port", str(free_port()),
        "--out", str(out), timeout_s=420,
    )
    assert code == 0, f"exit {code} after {elapsed:.0f} s:\n{stdout[-4000:]}\n{stderr[-4000:]}"
    assert "radio: drone01 at 10.231." in stdout and "in namespace fleet-" in stdout
    assert "mission m1 finished: success" in stdout
    result = json.loads((out / "result.json").read_text())
    temperatures = [s["sensors"].get("temperature") for s in result["drones"]["drone01"]["samples"]]
    assert max(t for t in temperatures if t is not None) > 37  # the sensor program in drone01's namespace
    assert "drone01 system connect" in (out / "logs" / "drone01.log").read_text()
    run = re.search(r"in namespace (fleet-\d+-)", stdout).group(1)  # type: ignore[union-attr]
    assert not [ns for ns in list_netns() if ns.startswith(run)]  # all removed on exit (other runs may go on)
