"""Made-up drone ids on an open mesh (issue 79): a client publishes a copy of a real
drone's telemetry under many ids that never say what they are, while a real drone stays
ready and takes commands.

    .venv/bin/python bench/id_flood.py [--ids 20000] [--rate 2000] [--rss-bar-mib 20]

`fleet ground` (open mesh, defaults) and one `fleet agent --fc sim` run as child
processes on loopback; this process is the flooding client (one Zenoh session, `put`s
under `drone/<made-up id>/telem`, no `about`). Halfway through, the real drone is sent
`arm` through the API, and its state is read every 0.2 s throughout. Prints how many
ids the ground registered, what it logged, and its RSS growth; exits 1 when the growth
reaches the bar, when more made-up ids registered than the unannounced bucket allows,
or when the real drone left `ready` or refused the command.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgspec  # noqa: E402
import zenoh  # noqa: E402

from bench.procstat import rss_mib  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.zenoh_bus import zenoh_config  # noqa: E402
from dronefleet.ground.config import GroundConfig  # noqa: E402
from dronefleet.ground.registry import UNANNOUNCED_BURST  # noqa: E402
from dronefleet.schemas.codec import encode  # noqa: E402
from dronefleet.schemas.keys import Keys  # noqa: E402
from dronefleet.schemas.telemetry import Telemetry  # noqa: E402
from tests.harness import GroundFleet, drone_state

SETTLE_S = 3.0  # after the flood: what it left, not what is in flight


async def main(ids: int, rate: float, rss_bar_mib: float) -> None:
    keys = Keys()
    with tempfile.TemporaryDirectory() as tmp_name:
        fleet = GroundFleet(Path(tmp_name), {"drone01": "sim"})
        ground = fleet.ground
        try:
            async with fleet.client() as http:  # once drone01 is ready
                view = (await http.get("/drone/drone01", params={"data": "telem"})).json()
                real = msgspec.convert(view["telem"], Telemetry)
                before = rss_mib(ground.proc.pid)
                states: list[str | None] = []
                command: list[int] = []

                async def watch() -> None:
                    while True:
                        states.append(await drone_state(http, "drone01"))
                        await asyncio.sleep(0.2)

                async def command_midway() -> None:
                    await asyncio.sleep(ids / rate / 2)
                    command.append((await http.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code)

                watching = asyncio.get_running_loop().create_task(watch())
                midway = asyncio.get_running_loop().create_task(command_midway())
                started = time.monotonic()
                # An attacker's cheapest way: plain puts, no publisher declared per id
                flooder = zenoh.open(zenoh_config("client", connect=[ground.endpoint]))
                try:
                    for i in range(ids):
                        made_up = f"ghost{i:06d}"
                        flooder.put(keys.telem(made_up), encode(msgspec.structs.replace(real, drone_id=made_up)))
                        lag = started + (i + 1) / rate - time.monotonic()
                        if lag > 0:
                            await asyncio.sleep(lag)
                    flood_s = time.monotonic() - started
                    await midway
                    await asyncio.sleep(SETTLE_S)
                finally:
                    watching.cancel()
                    flooder.close()
                after = rss_mib(ground.proc.pid)
                registered = len((await http.get("/drone")).json())
                lines = (await http.get("/drone/logs", params={"loglevel": "warn"})).text.splitlines()
        finally:
            fleet.stop()
    allowed = UNANNOUNCED_BURST + GroundConfig().unannounced_per_s * (flood_s + SETTLE_S)
    said = [line for line in lines if "had not said what they are" in line]
    print(f"{ids} made-up ids at {ids / flood_s:.0f} ids/s over {flood_s:.1f} s (one real drone beside them)")
    print(f"  registered        : {registered - 1} made-up (bound {allowed:.0f}), and the real drone")
    print(f"  ground RSS        : {before:.1f} -> {after:.1f} MiB (+{after - before:.1f}, bar {rss_bar_mib:g})")
    print(f"  real drone states : {', '.join(sorted(map(str, set(states))))} ({len(states)} reads); arm midway: {command}")
    print(f"  log               : {said[-1] if said else 'no line about the dropped ids'}")
    if after - before >= rss_bar_mib:
        raise ScenarioFailed(f"the ground grew by {after - before:.1f} MiB, the bar is {rss_bar_mib:g}")
    if registered - 1 > allowed:
        raise ScenarioFailed(f"{registered - 1} made-up ids registered, more than the bucket's {allowed:.0f}")
    if not set(states) <= {"ready", "active"} or command != [200]:
        raise ScenarioFailed(f"the real drone was {sorted(map(str, set(states)))}, its command answered {command}")
    if not said:
        raise ScenarioFailed("the ground logged no line naming the ids it dropped")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ids", type=int, default=20_000)
    parser.add_argument("--rate", type=float, default=2000.0, help="made-up ids per second")
    parser.add_argument("--rss-bar-mib", type=float, default=20.0)
    args = parser.parse_args()
    asyncio.run(main(args.ids, args.rate, args.rss_bar_mib))
