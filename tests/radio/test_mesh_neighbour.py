"""A healthy drone stays heard while its own link to a neighbour turns lossy (issue 57),
on real packets with the real `fleet ground` and `fleet sim WORLD --agents --radio`.

drone01 hovers 20 m from the laptop with no loss on its own hop; drone02 stands 55 m
out in another direction (73 m from drone01: that link is lossy from the start) and
carries drone03, beyond it and out of the laptop's reach. drone02 flies out to 92 m
and back, twice: its link to drone01 goes from lossy to lost and back, its own hop to
the laptop too. At the ground drone01 must never go 1.5 s unheard at 5 Hz, never lose
its token, never be logged `Link lost`; and drone03 takes a command as soon as the
ground lists it (through drone02).
"""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.geo import destination, distance_m
from tests.harness import ChildProcess
from tests.radio.emulated import GROUND, RADIO_A, command, drone, log_lines, relay_line, state_is
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.radio]

BEARING = 150.0  # drone02's way, away from drone01 (north)
GAP_S = 1.5


def at(metres: float, bearing: float) -> tuple[float, float]:
    return destination(GROUND[0], GROUND[1], metres, bearing)


@RADIO_A
@pytest.mark.slow(90)
async def test_a_healthy_drone_stays_heard_while_its_link_to_a_neighbour_turns_lossy(
        tmp_path: Path, processes: list[ChildProcess]) -> None:  # noqa: F811
    r = at(55, BEARING)  # drone02's spot, where its flights end
    ground, sim = await relay_line(tmp_path, processes, at(20, 0.0), r, at(105, BEARING))
    heard: list[float] = []
    tokens: list[tuple[float, bool]] = []
    watcher = await ZenohBus.open("client", [f"tcp/127.0.0.1:{ground.zenoh_port}"])
    try:
        watcher.subscribe("drone/drone01/telem", lambda s: heard.append(time.monotonic()))
        watcher.watch_liveliness("drone/drone01/alive", lambda key, alive: tokens.append((time.monotonic(), alive)))
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            await until(lambda: state_is(http, "drone01", "ready"), 60, "drone01 ready")
            await until(lambda: state_is(http, "drone02", "ready"), 60, "drone02 ready")
            # The first moment drone03 is listed (through drone02), it takes a command.
            await until(lambda: drone(http, "drone03"), 60, "drone03 listed at the ground")
            sent = time.monotonic()
            reply = await http.post("/drone/drone03/cmd", json={"cmd": "arm"})
            assert reply.status_code in (200, 409), reply.text  # 409: not ready yet (its health), never 504
            assert time.monotonic() - sent < 3.0
            # drone02 flies out and back twice alone (a bundle: out there the ground
            # cannot reach it), ending where it took off from.
            far = at(92, BEARING)
            legs = [{"cmd": "goto", "lat": p[0], "lon": p[1], "speed": 8} for p in (far, r, far, r)]
            bundle = {"on_link_loss": "continue", "timeout_s": 300, "steps": [{"cmd": "takeoff", "alt": 10}, *legs]}
            await command(http, "drone02", cmd="arm")
            pushed = await http.post("/drone/drone02/bundle", json=bundle)
            assert pushed.status_code == 200, pushed.text
            start = time.monotonic()
            await until(lambda: _near(http, "drone02", far), 60, "drone02 on its way out")
            state = await until(lambda: _bundle_done(http, "drone02", pushed.json()["bundle_id"]), 180, "drone02 back at 55 m")
            end = time.monotonic()
            assert state == "done", state  # it flew every leg
            lines = await log_lines(http, "drone01")
    finally:
        await watcher.close()
    during = [t for t in heard if start <= t <= end]
    gaps = [b - a for a, b in zip([start, *during], [*during, end], strict=True)]
    assert end - start > 15 and len(during) >= 4 * (end - start), (end - start, len(during))
    assert max(gaps) < GAP_S, f"drone01 unheard {max(gaps):.2f} s at 5 Hz"
    assert not [t for t, alive in tokens if not alive], tokens
    assert not [line for line in lines if "Link lost" in line], lines


async def _near(http: httpx.AsyncClient, drone_id: str, spot: tuple[float, float], within_m: float = 40) -> bool:
    view = await drone(http, drone_id)
    pos = ((view or {}).get("telem") or {}).get("position")
    return pos is not None and distance_m(spot[0], spot[1], pos["lat"], pos["lon"]) < within_m


async def _bundle_done(http: httpx.AsyncClient, drone_id: str, bundle_id: str) -> str | None:
    r = await http.get(f"/drone/{drone_id}/bundle/{bundle_id}")
    ended = r.status_code == 200 and r.json()["state"] in ("done", "failed", "ended", "cancelled")
    return str(r.json()["state"]) if ended else None
