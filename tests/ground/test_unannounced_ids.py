"""Made-up drone ids on an open mesh (issue 79): telemetry under new ids that never say
what they are registers only from the registry's bucket, reaches no watcher, and is
asked `about` a few at a time; an id whose agent answers registers at once. In-process
bus, virtual clock."""

from __future__ import annotations

import asyncio
from pathlib import Path

from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.ground.config import GroundConfig
from dronefleet.ground.eventlog import EventLog
from dronefleet.ground.registry import UNANNOUNCED_BURST
from dronefleet.ground.station import GroundStation
from dronefleet.schemas.about import About
from dronefleet.schemas.codec import encode
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import Position, Telemetry

GHOSTS = 500


async def test_a_flood_of_unannounced_ids_registers_only_the_bucket_and_an_answering_drone_registers(tmp_path: Path) -> None:
    clock, keys, network = VirtualClock(), Keys(), MemoryNetwork()
    ground_bus, flooder, agent = MemoryBus(network, "ground"), MemoryBus(network, "flooder"), MemoryBus(network, "drone01")
    station = GroundStation(GroundConfig(unannounced_per_s=0), ground_bus, EventLog(tmp_path / "events.db"), clock=clock)
    asked: list[str] = []

    async def about(key: str, payload: bytes) -> bytes:
        asked.append(key)
        return encode(About(drone_id="drone01", timestamp=clock.time_ms()))

    agent.serve(keys.about("drone01"), about)
    heard: list[str] = []
    station.listen(lambda event: heard.append(event.data.drone_id) if event.kind == "telemetry" else None)
    running = asyncio.ensure_future(station.run())
    try:
        def sample(drone_id: str) -> bytes:
            return encode(Telemetry(drone_id=drone_id, timestamp=clock.time_ms(), armed=False,
                                    position=Position(lat=40.6334, lon=-8.66081, alt=8.2, rel_alt=0.0)))

        await clock.advance(0.5)
        for i in range(GHOSTS):
            flooder.publish(keys.telem(f"ghost{i:04d}"), sample(f"ghost{i:04d}"))
        await clock.advance(1.0)
        assert len(station.registry.ids()) == UNANNOUNCED_BURST
        agent.publish(keys.telem("drone01"), sample("drone01"))  # past the bucket: asked, then let in
        await clock.advance(1.0)
        assert asked, "the ground never asked drone01 what it is"
        agent.publish(keys.telem("drone01"), sample("drone01"))
        await clock.advance(1.0)
        assert "drone01" in station.registry
        assert set(heard) <= {*station.registry.ids()}, "telemetry of ids not registered reached a mission"
    finally:
        running.cancel()
        await asyncio.gather(running, return_exceptions=True)
