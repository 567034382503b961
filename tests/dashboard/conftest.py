"""The dashboard tests' fixtures: one Chromium, a page on a ground, fleets, a tile server."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
from playwright.async_api import Browser

from bench.dashboard_frames import (
    DESKTOP,
    launch_chromium,
)
from tests.dashboard.page import FENCE, SPAWNS, Dashboard, chromium
from tests.dashboard.tiles import TileServer
from tests.harness import GroundFleet


# One Chromium per worker, a fresh context (cookies, storage, page) per test: a launch
# cost 0.9 CPU-seconds, 15 of the suite's (ADR 0011). The tests of tests/dashboard run on
# the session's event loop (page.SESSION_LOOP), where the browser lives.
@pytest_asyncio.fixture(scope="session", loop_scope="session")
async def browser() -> AsyncIterator[Browser]:
    async with launch_chromium(chromium()) as browser:
        yield browser


@pytest_asyncio.fixture(loop_scope="session")
async def dashboard(browser: Browser, tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[Dashboard]:
    context = await browser.new_context(viewport=DESKTOP)
    try:
        dash = Dashboard(await context.new_page())
        yield dash
    finally:
        shot = tmp_path / f"{request.node.name}.png"
        with contextlib.suppress(Exception):  # the screenshot is for the reader; never the failure
            await dash.page.screenshot(path=str(shot))
            print(f"screenshot: {shot}")
        await context.close()


def fleet_of(tmp: Path, spawns: dict[str, tuple[float, float]], agent_config: dict[str, Any] | None = None,
           **ground_config: Any) -> Iterator[GroundFleet]:
    fcs = {d: f"sim://?lat={lat}&lon={lon}&alt=8.2" for d, (lat, lon) in spawns.items()}
    fleet = GroundFleet(tmp, fcs, agent_config, **ground_config)
    try:
        yield fleet
    finally:
        fleet.stop()


@pytest.fixture
def fenced_fleet(tmp_path: Path) -> Iterator[GroundFleet]:
    yield from fleet_of(tmp_path, SPAWNS, geofence={"polygon": FENCE}, dashboard={"heat_sources": [
        {"lat": 40.633849, "lon": -8.660637, "radius": 50, "temp": 60},
    ]})


@pytest.fixture
def mission_fleet(tmp_path: Path) -> Iterator[GroundFleet]:
    # Parked 11 m apart: closer, a takeoff under a hovering drone is a conflict (SPEC §11).
    spawns = {d: (40.633400, -8.660810 + 0.00013 * i) for i, d in enumerate(("drone01", "drone02"))}
    yield from fleet_of(tmp_path, spawns, {"telemetry_rate_ms": 200, "takeoff_altitude": 5.0},
                      dashboard={"ground_station": {"lat": 40.633300, "lon": -8.660900}})


# ---- 1. drones: select, telemetry, commands, refusals, goto by clicking the map ---------


@pytest.fixture
def tile_server() -> Iterator[TileServer]:
    server = TileServer()
    try:
        yield server
    finally:
        server.close()
