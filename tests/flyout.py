"""A drone flown straight out of the laptop's range, on real packets and in fast time:
what it reported of its link to the ground on the way, and when the ground lost it
(issue 57). The test (tests/agent/test_link_quality.py) and the bench (bench/link_flyout.py)
share it, so both judge the same scenario.

On real packets: the real `fleet ground` in this namespace, `fleet sim WORLD --agents
--radio` for the drone, `fleet sub` inside the drone's namespace recording what its agent
said (also what never reached the ground). In fast time: SimField on the same world.
"""

from __future__ import annotations

import asyncio
import bisect
import json
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import httpx

from dronefleet.agent.config import AgentConfig
from dronefleet.agent.link import LostLinkPolicy
from dronefleet.compose import SimField
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.sim.radio import RadioModel
from dronefleet.sim.world import DroneSpec, Spot, World
from tests.harness import GroundProcess, stop_all
from tests.radio.emulated import OnBoard, RadioSim, command, state_is
from tests.waiting import advance_until, until

GROUND = (40.633490, -8.660815)
START_M = 20.0
ALT_M = 10.0
DEGRADED = 0.5  # the quality under which the ground warns `link degraded`
# The lost-link policy lets the drone fly on out: the fly-out ends where the ground lost
# it. (Holding where its own link first went quiet for 3 s, a drone could hover in the
# unstable band with a link that keeps coming back: telemetry trickling in, the ground
# never lost it, and the fly-out ran to its time limit — seen once in fast time.)
POLICY = {"timeout_s": 3, "action": "continue", "return_after_s": 600}


def north(metres: float) -> tuple[float, float]:
    return destination(GROUND[0], GROUND[1], metres, 0.0)


@dataclass
class Flyout:
    """Times in seconds (wall on real packets, virtual in fast time), one clock each."""

    reports: list[tuple[float, float, float, float]] = field(default_factory=list)  # (t, distance m, quality, loss)
    lost_at: float | None = None  # the ground first showed the drone `unknown`
    track: list[tuple[float, float]] = field(default_factory=list)  # (t, distance m) from its telemetry

    def degraded_s(self) -> float | None:
        """How long the quality had stayed under DEGRADED when the ground lost the drone
        (None: never lost, or quality never under it before)."""
        if self.lost_at is None:
            return None
        before = [r for r in self.reports if r[0] <= self.lost_at]
        good = [t for t, _, q, _ in before if q >= DEGRADED]
        last_good = max(good, default=None)
        first = next((t for t, _, q, _ in before if q < DEGRADED and (last_good is None or t > last_good)), None)
        return None if first is None else self.lost_at - (last_good if last_good is not None else first)

    def first_degraded_m(self) -> float | None:
        return next((d for _, d, q, _ in self.reports if q < DEGRADED), None)

    def first_degraded_at(self) -> float | None:
        return next((t for t, _, q, _ in self.reports if q < DEGRADED), None)

    def reached_at(self, distance_m: float) -> float | None:
        """When the drone first stood this far out."""
        return next((t for t, d in self.track if d >= distance_m), None)


def _distance(track: list[tuple[float, float]], t: float) -> float:
    """How far out the drone was at `t`, from its (time, distance) track: between the
    two samples around it, in proportion (fast time samples a drone at 5 m/s every 5 m)."""
    after = bisect.bisect_left(track, t, key=lambda sample: sample[0])
    if after == len(track) or after == 0:
        return track[-1 if after == len(track) else 0][1]
    (t0, d0), (t1, d1) = track[after - 1], track[after]
    return d0 + (d1 - d0) * (t - t0) / (t1 - t0) if t1 > t0 else d1


def _flyout(said: list[tuple[float, str, dict[str, Any]]], lost_at: float | None) -> Flyout:
    track = [(t, distance_m(GROUND[0], GROUND[1], m["position"]["lat"], m["position"]["lon"])) for t, k, m in said
             if k.endswith("/telem") and m.get("position")]
    reports = [(t, _distance(track, t), m["quality"], m["loss"]) for t, k, m in said
               if k.endswith("/link") and m["peer"] == "ground"]
    return Flyout(reports, lost_at, track)


async def fast_flyout(radio: RadioModel, speed_mps: float, seed: int) -> Flyout:
    world = World(ground_station=Spot(lat=GROUND[0], lon=GROUND[1]), radio=radio,
                  drones=[DroneSpec(id="drone01", lat=north(START_M)[0], lon=north(START_M)[1])])
    sim = SimField(world, seed=seed, agent_config=AgentConfig(lost_link=LostLinkPolicy(**POLICY)))  # type: ignore[arg-type]
    said: list[tuple[float, str, dict[str, Any]]] = []
    clock = sim.clock
    await sim.start()
    try:
        sim._bus("drone01").subscribe("drone/drone01/**", lambda s: said.append(
            (clock.monotonic(), s.key, json.loads(s.payload))), maxsize=100_000)
        registry = sim.station.registry

        def state() -> str:
            return registry.info("drone01").state if "drone01" in registry else "unheard"

        async def command(**body: Any) -> None:
            body["command_id"] = f"flyout-{body['cmd']}"
            task = asyncio.ensure_future(sim.station.command("drone01", json.dumps(body).encode()))
            await advance_until(sim, task.done, 30)
            task.result()

        await advance_until(sim, lambda: state() == "ready", 10)
        await command(cmd="arm")
        await command(cmd="takeoff", alt=ALT_M)
        await advance_until(sim, lambda: state() == "hold", 60)
        far = north(radio.lost_m + 60)
        out = asyncio.ensure_future(sim.station.command("drone01", json.dumps(
            {"cmd": "goto", "command_id": "out", "lat": far[0], "lon": far[1], "speed": speed_mps}).encode()))
        await advance_until(sim, lambda: state() == "unknown", (radio.lost_m + 60) / speed_mps + 60)
        lost_at = clock.monotonic()
        out.cancel()
    finally:
        await sim.close()
    return _flyout(said, lost_at)


async def real_flyout(tmp: Path, radio: RadioModel, speed_mps: float) -> Flyout:
    """Needs CAP_NET_ADMIN (the emulated radio); `tmp` must exist. Everything it
    starts is stopped."""
    started: list[Any] = []
    try:
        ground = GroundProcess(tmp, zenoh_host="0.0.0.0")
        started.append(ground)
        await ground.ready()
        start = north(START_M)
        sim = RadioSim(tmp, ground, [{"id": "drone01", "lat": start[0], "lon": start[1]}],
                       {"radio": {"good_m": radio.good_m, "lost_m": radio.lost_m}},
                       lost_link=POLICY, probe_period_ms=1000, probe_window=10)
        started.append(sim)
        await sim.up()
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            await until(partial(state_is, http, "drone01", "ready"), 60, "drone01 ready at the ground")
            onboard = OnBoard(tmp, sim.netns("drone01"), "drone01")
            started.append(onboard)
            await until(lambda: onboard.messages("/link"), 30, "link reports on board")
            await command(http, "drone01", cmd="arm")
            await command(http, "drone01", cmd="takeoff", alt=ALT_M)
            await until(partial(state_is, http, "drone01", "hold"), 60, "drone01 hovering")
            far = north(radio.lost_m + 60)
            await command(http, "drone01", cmd="goto", lat=far[0], lon=far[1], speed=speed_mps)
            await until(partial(state_is, http, "drone01", "unknown"), 120, "the ground losing drone01")
            lost_at = time.time()
        said = [(m["timestamp"] / 1000.0, f"drone/drone01/{kind}", m)
                for kind in ("telem", "link") for m in onboard.messages(f"/{kind}")]
        said.sort(key=lambda x: x[0])
        return _flyout(said, lost_at)
    finally:
        stop_all(reversed(started))

