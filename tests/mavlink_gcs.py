"""A bare MAVLink 2 ground station for the simulator's tests: what a GCS sends and
what comes back, with no MAVSDK between."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from pymavlink.dialects.v20 import common as mav2

from dronefleet.sim.mavlink_endpoint import MavlinkVehicle
from dronefleet.sim.vehicle import Vehicle
from tests.ports import free_udp_base
from tests.waiting import Collector


class Gcs(asyncio.DatagramProtocol):
    """A bare MAVLink 2 ground station (255/190) on a loopback socket."""

    def __init__(self) -> None:
        self.mav = mav2.MAVLink(None, srcSystem=255, srcComponent=mav2.MAV_COMP_ID_MISSIONPLANNER)
        self.mav.robust_parsing = True
        self.got = Collector()
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        for msg in self.mav.parse_buffer(data) or []:
            self.got(msg)

    async def ask(self, msg: mav2.MAVLink_message, reply: str) -> mav2.MAVLink_message:
        """Send `msg` to the vehicle and wait for its next `reply`."""
        assert self.transport is not None
        start = len(self.got.items)
        self.transport.sendto(msg.pack(self.mav))
        return await self.got.wait_for(lambda m: m.get_type() == reply, 5, reply, start=start)


@asynccontextmanager
async def answering_autopilot(autopilot: str, spawn: tuple[float, float, float]) -> AsyncIterator[tuple[MavlinkVehicle, Gcs]]:
    """One simulated `autopilot` answering a bare ground station; nobody steps its
    vehicle but the test."""
    endpoint = MavlinkVehicle(Vehicle(*spawn), 1, [("127.0.0.1", free_udp_base(1))], autopilot=autopilot)
    await endpoint.start(("127.0.0.1", 0))
    transport, gcs = await asyncio.get_running_loop().create_datagram_endpoint(
        Gcs, remote_addr=("127.0.0.1", endpoint.local_port))
    try:
        yield endpoint, gcs
    finally:
        transport.close()
        endpoint.close()
