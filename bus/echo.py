"""The laptop's echo on the radio (ADR 0003): a datagram sent back for each one received.

An agent measures its own hop to the laptop the way it measures its neighbours (a Zenoh
scout and its Hello): one datagram a round and its answer, never retransmitted, so
every loss on the air shows, and no link is held over the hop to measure it. The ground
answers on UDP at the port number of each of its Zenoh listeners (a TCP port: the UDP
one beside it is free unless Zenoh also listens on UDP there, which the ground then
skips, logged). Only short datagrams carrying ECHO_TAG are answered, so the echo
reflects nothing bigger than it was sent.
"""

from __future__ import annotations

import asyncio
import logging

from dronefleet.schemas.endpoints import ip_endpoint

log = logging.getLogger(__name__)

ECHO_TAG = b"fleet-echo "
ECHO_MAX = 64


class _Echo(asyncio.DatagramProtocol):
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: tuple[str | object, ...]) -> None:
        if data.startswith(ECHO_TAG) and len(data) <= ECHO_MAX:
            self.transport.sendto(data, addr)  # type: ignore[attr-defined]


def echo_address(endpoint: str) -> tuple[str, int] | None:
    """Where the laptop behind a Zenoh endpoint (tcp/HOST:PORT, tls/…; not port 0) echoes: UDP HOST:PORT."""
    parsed = ip_endpoint(endpoint)
    if parsed is None or parsed[0] not in ("tcp", "tls") or parsed[2] == 0:
        return None
    return parsed[1], parsed[2]


async def serve_echoes(endpoints: list[str]) -> list[asyncio.DatagramTransport]:
    """An echo beside each TCP/TLS listener of the ground (closed by the caller)."""
    loop = asyncio.get_running_loop()
    out = []
    for endpoint in endpoints:
        address = echo_address(endpoint)
        if address is None:
            continue
        try:
            transport, _ = await loop.create_datagram_endpoint(_Echo, local_addr=address)
        except OSError as exc:
            log.warning("no radio echo on udp/%s:%d (%s): drones will not measure their hop to the laptop",
                        address[0], address[1], exc)
            continue
        out.append(transport)
    return out
