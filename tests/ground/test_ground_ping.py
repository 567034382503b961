"""The ground's `ground/ping` queryable, which every agent's link probe asks, is declared
afresh when a drone whose liveliness token was lost comes back (ADR 0003): after a link
flap a drone's router was seen holding no route to it for minutes while the drone's
telemetry flowed, so the drone took the ground for lost. In-process bus, virtual clock."""

from __future__ import annotations

import asyncio
from pathlib import Path

from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.ground.config import GroundConfig
from dronefleet.ground.eventlog import EventLog
from dronefleet.ground.station import PING_REFRESH_MIN_S, GroundStation
from dronefleet.schemas.keys import Keys


async def test_a_drone_back_on_the_mesh_gets_the_ground_ping_declared_afresh_at_most_so_often(tmp_path: Path) -> None:
    clock, keys, network = VirtualClock(), Keys(), MemoryNetwork()
    ground_bus, drone = MemoryBus(network, "ground"), MemoryBus(network, "drone01")
    station = GroundStation(GroundConfig(), ground_bus, EventLog(tmp_path / "events.db"), clock=clock)
    running = asyncio.ensure_future(station.run())
    try:
        await clock.advance(0.5)
        assert station.ping is not None and station.ping.refreshes == 0
        token = drone.announce(keys.alive("drone01"))
        await clock.advance(0.5)
        assert station.ping.refreshes == 0  # a drone's first token is no news
        token.close()
        await clock.advance(0.5)
        token = drone.announce(keys.alive("drone01"))
        await clock.advance(0.5)
        assert station.ping.refreshes == 1 and station.ping.form == "ground/ping/**"
        reply = await drone.query(keys.ground_ping(), b"probe", timeout_s=1.0)
        assert reply == b"probe"  # answered under the new form, the old one gone
        token.close()
        await clock.advance(0.2)
        token = drone.announce(keys.alive("drone01"))
        await clock.advance(0.2)
        assert station.ping.refreshes == 1  # a flapping drone: at most once per PING_REFRESH_MIN_S
        token.close()
        await clock.advance(PING_REFRESH_MIN_S)
        token = drone.announce(keys.alive("drone01"))
        await clock.advance(0.2)
        assert station.ping.refreshes == 2 and station.ping.form == "ground/ping"
        token.close()
    finally:
        running.cancel()
        await asyncio.gather(running, return_exceptions=True)
