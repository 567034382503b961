"""The field network's three scenarios in fast time (issue 12, SPEC §8): the radio model
on the in-process bus, hop by hop over the mesh, on the virtual clock, seeded.

The same scenarios as tests/radio/ on real packets: out of range and
back, a relay through a neighbour, an on-board sensor through an outage. Each runs
twice with one seed and must replay exactly: every message the drones said (recorded
on board, so also what never reached the ground) and every line of the ground's log.
"""

from __future__ import annotations

import asyncio
import itertools
import json
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from dronefleet.agent.config import AgentConfig
from dronefleet.agent.link import LostLinkPolicy
from dronefleet.bus.port import BusError
from dronefleet.compose import SimField
from dronefleet.schemas.errors import CommandRejected
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.schemas.keys import Keys
from dronefleet.sim.radio import GROUND, RadioModel
from dronefleet.sim.world import DroneSpec, Spot, World

BASE = (40.633490, -8.660815)
SEED = 7
DOUBT_M = 76  # m: the default radio loses 40 % of what crosses there
Trace = list[tuple[float, str, Any]]


def north(metres: float) -> tuple[float, float]:
    return destination(BASE[0], BASE[1], metres, 0.0)


class Field:
    """A SimField on the default radio, with what each drone says recorded on board."""

    def __init__(self, drones: list[DroneSpec], lost_link: LostLinkPolicy, seed: int = SEED,
                 telemetry_rate_ms: int = 200, doubt_telemetry_rate_ms: int = 250) -> None:
        world = World(ground_station=Spot(lat=BASE[0], lon=BASE[1]), drones=drones, radio=RadioModel())
        config = AgentConfig(telemetry_rate_ms=telemetry_rate_ms, doubt_telemetry_rate_ms=doubt_telemetry_rate_ms,
                             lost_link=lost_link)
        self.sim = SimField(world, seed=seed, agent_config=config)
        self.said: Trace = []  # (t, key, message) heard on each drone's own node
        self.ids = [d.id for d in drones]
        self.lines: list[str] = []  # the ground's log, kept when the field closes

    async def __aenter__(self) -> Field:
        await self.sim.start()
        for drone_id in self.ids:
            self.sim._bus(drone_id).subscribe(
                f"drone/{drone_id}/**", lambda s: self.said.append((self.clock.monotonic(), s.key, json.loads(s.payload))),
                maxsize=100_000,
            )
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.lines = [f"{line.timestamp} {line.drone_id} {line.message}" for _, line in self.sim.events.query()]
        await self.sim.close()

    @property
    def clock(self) -> Any:
        return self.sim.clock

    def state(self, drone_id: str) -> str:
        """Its state at the ground; "unheard" before the ground first heard it (a drone out of
        the laptop's reach comes in through a neighbour once its agent bridges to one)."""
        registry = self.sim.station.registry
        return registry.info(drone_id).state if drone_id in registry else "unheard"

    async def until(self, predicate: Callable[[], bool], max_s: float, what: str) -> float:
        """Advance virtual time in 0.1 s steps until `predicate` holds; the time it did."""
        for _ in range(round(max_s * 10)):
            if predicate():
                return self.clock.monotonic()
            await self.clock.advance(0.1)
        raise AssertionError(f"not within {max_s:g} simulated seconds: {what}")

    async def run(self, step: Awaitable[Any], max_s: float = 30) -> Any:
        task = asyncio.ensure_future(step)
        await self.until(task.done, max_s, "the step to end")
        return task.result()

    async def command(self, drone_id: str, **body: Any) -> Any:
        body["command_id"] = f"test-{body['cmd']}-{self.clock.time_ms()}"
        return await self.run(self.sim.station.command(drone_id, json.dumps(body).encode()))

    def log(self, drone_id: str) -> list[str]:
        return [line.message for _, line in self.sim.events.query([drone_id])]

    def system_states(self, drone_id: str) -> list[tuple[str, str]]:
        return [(m["state"], m.get("reason") or "") for _, k, m in self.said
                if k == f"drone/{drone_id}/status" and m.get("component") == "system"
                and m["state"] in ("link_lost", "failsafe", "link_restored")]

    def trace(self) -> tuple[Trace, list[str]]:
        return self.said, self.lines


async def out_of_range_and_back(seed: int = SEED) -> Field:
    start = north(20)
    async with Field([DroneSpec(id="drone01", lat=start[0], lon=start[1], sensors=["temperature"])],
                     LostLinkPolicy(timeout_s=3, action="hold", return_after_s=6), seed) as f:
        await f.until(lambda: f.state("drone01") == "ready", 10, "drone01 ready")
        await f.command("drone01", cmd="arm")
        await f.command("drone01", cmd="takeoff", alt=10)
        await f.until(lambda: f.state("drone01") == "hold", 60, "drone01 hovering")
        far = north(150)
        await f.command("drone01", cmd="goto", lat=far[0], lon=far[1], speed=2)
        await f.until(lambda: "Link lost" in " ".join(f.log("drone01")), 90, "the ground's 'Link lost'")
        await f.until(lambda: any(m.startswith("Link restored") for m in f.log("drone01")), 120, "'Link restored'")
        await f.until(lambda: f.state("drone01") == "ready", 120, "drone01 home and ready")
    return f


async def relay_through_a_neighbour(seed: int = SEED) -> tuple[Field, dict[str, Any]]:
    a, b = north(50), north(105)
    seen: dict[str, Any] = {}
    async with Field([DroneSpec(id="droneA", lat=a[0], lon=a[1]), DroneSpec(id="droneB", lat=b[0], lon=b[1])],
                     LostLinkPolicy(timeout_s=60, action="continue"), seed) as f:
        air = f.sim.air
        assert air is not None
        await f.until(lambda: f.state("droneB") == "ready", 10, "droneB ready at the ground")
        seen["path"] = air.path("droneB", GROUND)
        seen["arm"] = (await f.command("droneB", cmd="arm")).accepted  # the reply came back through A
        await f.command("droneB", cmd="disarm")

        await f.command("droneA", cmd="arm")
        await f.command("droneA", cmd="takeoff", alt=5)
        await f.until(lambda: f.state("droneA") == "hold", 60, "droneA hovering")
        away = destination(BASE[0], BASE[1], 55, 180.0)  # 55 m south: 160 m from B
        await f.command("droneA", cmd="goto", lat=away[0], lon=away[1], speed=10)
        await f.until(lambda: f.state("droneB") == "unknown", 60, "droneB unreachable once droneA left")
        try:
            await f.command("droneB", cmd="arm")
        except (BusError, CommandRejected) as exc:
            seen["refused"] = type(exc).__name__
        await f.command("droneA", cmd="goto", lat=a[0], lon=a[1], speed=10)

        def a_back() -> bool:  # within good range (60 m) of B again
            p = f.sim.vehicles["droneA"].position()
            return distance_m(b[0], b[1], p.lat, p.lon) < 60

        back_at = await f.until(a_back, 60, "droneA back within range of droneB")
        seen["back_after_s"] = await f.until(lambda: f.state("droneB") != "unknown", 15, "droneB again") - back_at
        seen["path_again"] = air.path("droneB", GROUND)
    return f, seen


async def sensor_through_an_outage(seed: int = SEED) -> tuple[Field, dict[str, Any]]:
    """The drone on the ground, 120 m away: out of range from its start. Its agent
    keeps getting its own sensor's readings all the while."""
    spot = north(120)
    async with Field([DroneSpec(id="drone01", lat=spot[0], lon=spot[1], sensors=["temperature"])],
                     LostLinkPolicy(timeout_s=3, action="hold"), seed) as f:
        agent_got: list[float] = []
        f.sim._bus("drone01").subscribe(Keys().sensor("drone01", "temperature"),
                                        lambda s: agent_got.append(f.clock.monotonic()))
        start = f.clock.monotonic()
        await f.until(lambda: f.clock.monotonic() - start >= 30, 31, "30 s")
        ground_knows = "drone01" in f.sim.station.registry
    return f, {"readings": agent_got, "ground_knows": ground_knows, "start": start}


async def test_out_of_range_and_back_in_fast_time() -> None:
    f = await out_of_range_and_back()
    # The drone's own measurement: where its quality to the ground first fell under 0.5.
    track = [(t, m["position"]) for t, k, m in f.said if k.endswith("/telem") and m.get("position")]
    reports = [(t, m["quality"]) for t, k, m in f.said if k.endswith("/link") and m["peer"] == GROUND]
    first_bad = next(t for t, q in reports if q < 0.5)
    at = min(track, key=lambda tp: abs(tp[0] - first_bad))[1]
    dist = distance_m(BASE[0], BASE[1], at["lat"], at["lon"])
    assert 60 <= dist <= 100, f"quality fell under 0.5 at {dist:.0f} m"

    states = f.system_states("drone01")
    order = [next(i for i, x in enumerate(states) if x[0] == "link_lost"), states.index(("failsafe", "hold")),
             states.index(("failsafe", "return")), max(i for i, x in enumerate(states) if x[0] == "link_restored")]
    assert order == sorted(order), states
    assert states[-1][0] == "link_restored" and states[-1][1].endswith("failsafe: hold, return"), states
    log = [line.split(" ", 2)[2] for line in f.lines if line.split(" ", 2)[1] == "drone01"]
    lost = next(i for i, m in enumerate(log) if m.startswith("Link lost"))
    assert any(m.startswith("Link restored") for m in log[lost:]), log


async def test_relay_through_a_neighbour_in_fast_time() -> None:
    f, seen = await relay_through_a_neighbour()
    assert seen["path"] == ["droneB", "droneA", GROUND]  # only through A: B-ground is out of range
    # Each drone's reports say how its probes were answered: A over its own link, B through A.
    hops = {d: {m.get("hops") for _, k, m in f.said if k == f"drone/{d}/link" and m["peer"] == GROUND} - {None}
            for d in ("droneA", "droneB")}
    assert hops == {"droneA": {1}, "droneB": {2}}, hops
    assert seen["arm"] is True
    assert seen["refused"] in ("Unreachable", "QueryTimeout", "CommandRejected")
    assert seen["back_after_s"] <= 5.0, seen
    assert seen["path_again"] == ["droneB", "droneA", GROUND]


async def test_a_drone_whose_lossy_link_closes_is_heard_through_its_bridge_at_once() -> None:
    """A worker flying out past the laptop's edge with a relay beyond: its direct link,
    lossy, carries its traffic until the lease runs out, and the samples in it go down
    with it. The agent publishes its telemetry as the link closes, over the bridge, not
    at its next period: waiting had left workers unheard 3.0-3.6 s where the lease
    accounts for 2 (fast-time corpus, ADR 0003). (1.3 s here: off the radio's 0.5 s
    rounds, so that the sample sent as the link closes stands apart from the period's.)"""
    a, b = north(50), north(20)
    async with Field([DroneSpec(id="droneA", lat=a[0], lon=a[1]), DroneSpec(id="droneB", lat=b[0], lon=b[1])],
                     LostLinkPolicy(timeout_s=60, action="continue"), telemetry_rate_ms=1300) as f:
        air = f.sim.air
        assert air is not None
        registry = f.sim.station.registry
        for drone_id in ("droneA", "droneB"):
            await f.until(lambda d=drone_id: f.state(d) == "ready", 10, f"{drone_id} ready")  # type: ignore[misc]
            await f.command(drone_id, cmd="arm")
            await f.command(drone_id, cmd="takeoff", alt=10)
        await f.until(lambda: f.state("droneA") == "hold" and f.state("droneB") == "hold", 60, "both hovering")
        far = north(115)
        await f.command("droneB", cmd="goto", lat=far[0], lon=far[1], speed=5)
        direct = air.links[("droneB", GROUND) if "droneB" < GROUND else (GROUND, "droneB")]
        closed_at = await f.until(lambda: not direct.up, 60, "droneB's direct link closing")
        assert air.path("droneB", GROUND) == ["droneB", "droneA", GROUND]
        heard = registry.telemetry("droneB").timestamp
        await f.until(lambda: registry.telemetry("droneB").timestamp != heard, 0.3, "droneB heard again")
        published = [t for t, k, _ in f.said if k == "drone/droneB/telem"]
        assert any(abs(t - closed_at) < 0.01 for t in published), (closed_at, published[-5:])


async def hover_on_a_lossy_link(doubt_telemetry_rate_ms: int, seed: int = SEED) -> dict[str, Any]:
    """One drone 10 s at 10 m from the laptop, then 40 s at DOUBT_M: when it published its
    telemetry, when the ground heard it."""
    at = north(10)
    async with Field([DroneSpec(id="drone01", lat=at[0], lon=at[1])], LostLinkPolicy(timeout_s=120, action="continue"),
                     seed, telemetry_rate_ms=1000, doubt_telemetry_rate_ms=doubt_telemetry_rate_ms) as f:
        registry = f.sim.station.registry
        agent = f.sim._agent_runtimes["drone01"]
        await f.until(lambda: f.state("drone01") == "ready", 10, "ready")
        await f.command("drone01", cmd="arm")
        await f.command("drone01", cmd="takeoff", alt=10)
        await f.until(lambda: f.state("drone01") == "hold", 60, "hovering")
        clean_from = f.clock.monotonic()
        doubts = []
        for _ in range(100):
            await f.clock.advance(0.1)
            doubts.append(agent.ground_unsure())
        clean_to = f.clock.monotonic()
        far = north(DOUBT_M)
        goto = asyncio.ensure_future(f.sim.station.command("drone01", json.dumps(
            {"cmd": "goto", "command_id": "out", "lat": far[0], "lon": far[1], "speed": 5}).encode()))
        heard: list[float] = []
        last = registry.telemetry("drone01").timestamp

        def there() -> bool:
            p = agent.fc.state().position
            return p is not None and distance_m(far[0], far[1], p.lat, p.lon) < 1
        await f.until(there, 60, f"at {DOUBT_M} m")
        lossy_from = f.clock.monotonic()
        for _ in range(400):
            await f.clock.advance(0.1)
            if registry.telemetry("drone01").timestamp != last:
                last = registry.telemetry("drone01").timestamp
                heard.append(f.clock.monotonic())
        goto.cancel()
        published = [t for t, k, _ in f.said if k == "drone/drone01/telem"]
        return {"clean_doubts": doubts, "lossy_from": lossy_from, "heard": heard,
                "clean": [t for t in published if clean_from <= t <= clean_to],
                "lossy": [t for t in published if t >= lossy_from]}


async def test_a_drone_in_doubt_of_the_ground_speaks_sooner() -> None:
    """While its agent is in doubt of the ground, telemetry every 250 ms, not every 1 s:
    over a hop that loses packets each sample is one more chance, and the ground hears
    the drone more often, in more of the seconds (ADR 0003). A clean link keeps the
    configured period."""
    sooner, same = await hover_on_a_lossy_link(250), await hover_on_a_lossy_link(1000)
    assert not any(sooner["clean_doubts"])
    assert [round(b - a, 2) for a, b in itertools.pairwise(sooner["clean"])] == [1.0] * (len(sooner["clean"]) - 1)
    steps = [round(b - a, 2) for a, b in itertools.pairwise(sooner["lossy"])]
    assert steps.count(0.25) > len(steps) / 2, steps
    assert [round(b - a, 2) for a, b in itertools.pairwise(same["lossy"])].count(0.25) == 0
    assert len(sooner["heard"]) > 1.5 * len(same["heard"]), (len(sooner["heard"]), len(same["heard"]))
    # In more of the seconds, over several seeds: one run's count of 40 seconds moves
    # by one or two with anything that shifts a draw.
    seconds = [0, 0]
    for seed in range(SEED, SEED + 4):
        for i, rate_ms in enumerate((250, 1000)):
            seconds[i] += len({int(t) for t in (await hover_on_a_lossy_link(rate_ms, seed))["heard"]})
    assert seconds[0] > seconds[1], seconds


async def test_an_onboard_sensor_feeds_its_agent_without_the_ground_in_fast_time() -> None:
    f, seen = await sensor_through_an_outage()
    assert not seen["ground_knows"]  # 120 m: the ground never heard of it
    # It never heard a ground, so it has none to lose: no loss reported, no failsafe (SPEC §8).
    assert not [s for s in f.system_states("drone01") if s[0] in ("link_lost", "failsafe")], f.system_states("drone01")
    readings = [t for t in seen["readings"] if t >= seen["start"]]
    assert len(readings) >= 30 / 0.2 * 0.95, len(readings)  # every 200 ms, none lost on board


@pytest.mark.parametrize("scenario", [out_of_range_and_back, relay_through_a_neighbour, sensor_through_an_outage])
async def test_the_same_seed_replays_exactly(scenario: Callable[..., Awaitable[Any]]) -> None:
    first, second = await scenario(), await scenario()
    one = first[0] if isinstance(first, tuple) else first
    two = second[0] if isinstance(second, tuple) else second
    assert one.trace() == two.trace()
    assert len(one.said) > 100


async def test_another_seed_flies_another_radio() -> None:
    one, two = await out_of_range_and_back(seed=1), await out_of_range_and_back(seed=2)
    assert one.trace() != two.trace()
