"""A relay corpus world on real packets (issue 32, ADR 0011): `fleet ground` and `fleet
sim WORLD --agents --radio` on the emulated radio, the world's mission with the relay
plugin; the surveyor must be heard at the ground at least every 3 s from the mission's
start to its end, and the mission must finish. Needs CAP_NET_ADMIN (root).

    .venv/bin/python bench/relay_real_packets.py [--world 206] [--mode chain] [--runs 1]

The suite keeps the short form on real packets (tests/radio/: the relay
plugin keeps a drone beyond the radio's range heard and commanded); this world flies
4-5 minutes in real time. Prints each run's outcome and the surveyor's longest gap;
exits 1 if a run did not finish or left a gap of 3 s or more.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import itertools
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx  # noqa: E402
import msgspec  # noqa: E402

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet import relay_corpus  # noqa: E402
from dronefleet.bus.port import Sample  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.sim import corpus  # noqa: E402
from dronefleet.sim.radio_net import has_net_admin  # noqa: E402
from tests.harness import GroundProcess, stop_all, submit  # noqa: E402
from tests.radio.emulated import RadioSim, state_is  # noqa: E402
from tests.waiting import until

GAP_S = 3.0


def _arrived(times: list[float], sample: Sample) -> None:
    times.append(time.monotonic())


async def run(tmp: Path, world_seed: int, mode: str) -> tuple[dict[str, Any], float]:
    """One run: the mission's record and the surveyor's longest gap at the ground (s)."""
    w = corpus.generate(world_seed)
    world = msgspec.to_builtins(w.world)
    started: list[Any] = []
    heard: list[float] = []
    try:
        ground = GroundProcess(tmp, zenoh_host="0.0.0.0", drone_timeout_ms=3000)
        started.append(ground)
        await ground.ready()
        sim = RadioSim(tmp, ground, world.pop("drones"), world_keys=world)
        started.append(sim)
        await sim.up()
        bus = await ZenohBus.open("client", [f"tcp/127.0.0.1:{ground.zenoh_port}"], wait=True)
        try:
            bus.subscribe(f"drone/{w.workers[0]}/telem", functools.partial(_arrived, heard))
            gs, line = w.world.ground_station, relay_corpus.MODES[mode]
            if gs is None or line is None:
                raise ScenarioFailed(f"world {world_seed} has no ground station, or mode {mode!r} no line")
            script = w.script(line.format(lat=gs.lat, lon=gs.lon))
            async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
                for d in sim.drone_ids:
                    await until(functools.partial(state_is, http, d, "ready"), 60, f"{d} ready at the ground")
                mission_id = await submit(http, script, "corpus")
                start = time.monotonic()

                async def ended() -> dict[str, Any] | None:
                    record: dict[str, Any] = (await http.get(f"/mission/{mission_id}")).json()
                    return record if record["end"] is not None else None

                record = await until(ended, 900, "the corpus mission to end")
                end = time.monotonic()
        finally:
            await bus.close()
    finally:
        stop_all(reversed(started))
    times = [start, *(t for t in heard if start <= t <= end), end]
    return record, max(b - a for a, b in itertools.pairwise(times))


async def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", type=int, default=206, help="corpus world seed (206: radio 53/72 m, surveyor 133 m out)")
    parser.add_argument("--mode", default="chain", choices=sorted(relay_corpus.MODES))
    parser.add_argument("--runs", type=int, default=1)
    args = parser.parse_args()
    if not has_net_admin():
        raise ScenarioFailed("the emulated radio needs CAP_NET_ADMIN (run as root)")
    failed = 0
    for i in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="relay-real-") as tmp:
            record, gap = await run(Path(tmp), args.world, args.mode)
        ok = record["status"] == "finished" and gap < GAP_S
        failed += not ok
        print(f"world {args.world}, mode {args.mode}, run {i + 1}: {record['status']} ({record['cause']}), "
              f"surveyor's longest gap {gap:.1f} s{'' if ok else ' — FAILED'}", flush=True)
    print(f"{args.runs - failed} of {args.runs} runs finished with the surveyor heard every {GAP_S:g} s", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
