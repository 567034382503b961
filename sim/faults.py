"""Fault injection into simulated vehicles, and the UDP control channel that carries it.

`fleet sim` opens one channel for all its vehicles (127.0.0.1:base-1); an agent
running the built-in sim (`--fc sim://?control=PORT`) opens one for its own vehicle.
Requests are JSON datagrams, e.g. `{"drone": "drone01", "fault": "rc_takeover"}`;
the reply says `{"ok": true}` or names the error. `fleet fault` is the client.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Callable

from dronefleet.sim.fault_kinds import FaultKind
from dronefleet.sim.vehicle import Vehicle

log = logging.getLogger(__name__)


def apply_fault(vehicle: Vehicle, fault: FaultKind | str, value: float | str | None = None) -> None:
    if fault == "rc_takeover":
        vehicle.inject_manual(True)
    elif fault == "rc_release":
        vehicle.inject_manual(False)
    elif fault == "low_battery":
        vehicle.inject_battery(float(value) if value is not None else 0.08)
    elif fault == "link_pull":
        vehicle.inject_link_loss(True)
    elif fault == "link_restore":
        vehicle.inject_link_loss(False)
    elif fault == "health_failure":
        vehicle.inject_health_failure(str(value or "accelerometer"))
    elif fault == "health_ok":
        vehicle.inject_health_failure()
    elif fault == "arm_denied":
        vehicle.inject_arm_denied(str(value or "preflight check failed"))
    elif fault == "arm_ok":
        vehicle.inject_arm_denied(None)
    elif fault == "gust":
        vehicle.inject_gust(float(value) if value is not None else 30.0)
    elif fault == "gps_loss":
        vehicle.inject_gps("no_fix")
    elif fault == "gps_ok":
        vehicle.inject_gps("fix_3d")
    else:
        raise ValueError(f"unknown fault {fault!r}")


class FaultChannel(asyncio.DatagramProtocol):
    """Server side: `lookup(drone)` finds the vehicle (ValueError if none),
    `status()` answers the `status` request with one line per vehicle."""

    def __init__(self, lookup: Callable[[str], Vehicle], status: Callable[[], dict[str, str]]) -> None:
        self.lookup = lookup
        self.status = status
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        try:
            request = json.loads(data)
            if request.get("fault") == "status":
                reply = {"ok": True, "status": self.status()}
            else:
                drone = str(request.get("drone", ""))
                apply_fault(self.lookup(drone), request["fault"], request.get("value"))
                log.warning("fault %s injected into %s", request["fault"], drone)
                reply = {"ok": True}
        except (ValueError, KeyError, TypeError) as exc:
            reply = {"ok": False, "error": str(exc)}
        assert self.transport is not None
        self.transport.sendto(json.dumps(reply).encode(), addr)


async def open_fault_channel(port: int, channel: FaultChannel) -> asyncio.BaseTransport:
    transport, _ = await asyncio.get_running_loop().create_datagram_endpoint(lambda: channel, local_addr=("127.0.0.1", port))
    return transport


async def send_fault(drone: str, fault: str, value: str | None, control: tuple[str, int], timeout_s: float = 3.0) -> dict[str, object]:
    """Client side of the control channel (`fleet fault`, tests)."""
    loop = asyncio.get_running_loop()
    reply: asyncio.Future[bytes] = loop.create_future()

    class _Client(asyncio.DatagramProtocol):
        def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
            if not reply.done():
                reply.set_result(data)

    transport, _ = await loop.create_datagram_endpoint(_Client, remote_addr=control)
    try:
        body: dict[str, object] = {"drone": drone, "fault": fault}
        if value is not None:
            body["value"] = float(value) if value.replace(".", "", 1).isdigit() else value
        transport.sendto(json.dumps(body).encode())
        async with asyncio.timeout(timeout_s):
            return json.loads(await reply)
    finally:
        transport.close()
