"""The emulated radio as the radio tests use it: `fleet sim --agents --radio` (RadioSim),
on-board programs in a drone's namespace (OnBoard), the two radio groups, and what the
tests read of the ground (SPEC §8). Fixtures: tests/radio/conftest.py (a radio slot:
tests/conftest.py)."""

from __future__ import annotations

import itertools
import json
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from dronefleet.schemas.geo import destination
from dronefleet.sim.autopilot_params import BRISK_PX4
from dronefleet.sim.fleet_sim import CHILDREN_STOP_S
from dronefleet.sim.radio_net import list_netns
from tests.harness import ChildProcess, GroundProcess, fleet_command
from tests.ports import free_udp_base
from tests.waiting import until

REPO = Path(__file__).resolve().parents[2]  # the checkout: where benches and scripts run from
GROUND = (40.633490, -8.660815)
FIELD_ALT = 8.2
SIM_STOP_S = CHILDREN_STOP_S + 10  # `fleet sim --radio` gives its agents CHILDREN_STOP_S, then takes the radio down


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
            # the radio is under test, not PX4's start and landing times
            *(f"--param={name}={value:g}" for name, value in BRISK_PX4.items()),
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


async def relay_line(tmp: Path, processes: list[ChildProcess], near: tuple[float, float], mid: tuple[float, float],
                     far: tuple[float, float]) -> tuple[GroundProcess, RadioSim]:
    """A `fleet ground` and three drones on the radio, none failing safe for a minute:
    drone01 near the laptop, drone02 (which may relay) further out, drone03 beyond it."""
    ground = GroundProcess(tmp, zenoh_host="0.0.0.0")
    processes.append(ground)
    await ground.ready()
    sim = RadioSim(tmp, ground, [
        {"id": "drone01", "lat": near[0], "lon": near[1]},
        {"id": "drone02", "lat": mid[0], "lon": mid[1], "roles": ["survey", "relay"]},
        {"id": "drone03", "lat": far[0], "lon": far[1]},
    ], lost_link={"timeout_s": 60, "action": "continue"})
    processes.append(sim)
    await sim.up()
    return ground, sim


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


async def field_sensor(http: httpx.AsyncClient, sensor_id: str) -> dict[str, Any] | None:
    r = await http.get(f"/sensor/{sensor_id}")
    return r.json() if r.status_code == 200 and r.json()["readings"] else None


async def reading_of(http: httpx.AsyncClient, drone_id: str, kind: str) -> dict[str, Any] | None:
    view = await drone(http, drone_id)
    return next((r for r in (view or {}).get("sensors") or [] if r["type"] == kind), None)


async def drone01_logged(http: httpx.AsyncClient, text: str) -> bool:
    return any(text in line for line in await log_lines(http, "drone01"))


async def temperature_read(http: httpx.AsyncClient, drone_id: str) -> bool:
    view = (await http.get(f"/drone/{drone_id}", params={"data": "sensors"})).json()
    return any(r["type"] == "temperature" for r in view.get("sensors") or [])


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


async def reachable(http: httpx.AsyncClient, drone_id: str) -> bool:
    d = await drone(http, drone_id)
    return d is not None and d["info"]["state"] != "unknown"


def wait_sync(predicate: Any, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.1)
