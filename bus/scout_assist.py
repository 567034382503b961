"""Find neighbouring routers faster than Zenoh's own scouting does (ADR 0003).

A Zenoh 1.10 router scouts for neighbours at 0, 1, 3, 7 s after it opens and then
every 8 s for ever (`SCOUT_MAX_PERIOD` in zenoh's orchestrator; no configuration key
changes it), and a session cannot be told to connect to an endpoint after it has
opened. So a drone cut off from the ground found a neighbour coming back into range
only at one of their next scouts: 0–8 s later, which missed "reachable again within
5 s" about one time in six (measured on the emulated radio).

While the agent hears nothing from the ground it calls `NeighbourScout.round()` about
once a second. A round multicasts one Scout for routers on the mesh interface, as
Zenoh does. Every router that hears it answers with a Hello to this socket: its own
drone's router (from a local address) and each neighbour in range. A neighbour's
Hello is handed on, unchanged, to the local router's scouting socket, which treats it
exactly as an answer to its own scout: it connects if it is not connected already.
Nothing is decoded beyond the message id, and only datagrams from the local router
are ever sent to; the local router keeps every decision (autoconnect rules, ZID
check).
"""

from __future__ import annotations

import asyncio
import fcntl
import logging
import socket
import struct
from collections.abc import Callable
from typing import cast

log = logging.getLogger(__name__)

# Zenoh scouting (zenoh-protocol, VERSION 0x09): message ids in the low 5 bits of the
# header; a Scout is header, version, and the `what` matcher (router = 0b001).
SCOUT_ID, HELLO_ID, ID_MASK = 0x01, 0x02, 0x1F
PROTOCOL_VERSION = 0x09
SCOUT_ROUTERS = bytes((SCOUT_ID, PROTOCOL_VERSION, 0b001))
SCOUTING_GROUP = ("224.0.0.224", 7446)  # Zenoh's default scouting/multicast/address
SIOCGIFADDR = 0x8915


def interface_address(interface: str) -> str:
    """The IPv4 address of a network interface (raises OSError if it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        packed = fcntl.ioctl(s.fileno(), SIOCGIFADDR, struct.pack("256s", interface.encode()[:15]))
    return socket.inet_ntoa(packed[20:24])


def is_local_address(ip: str) -> bool:
    """Whether this host (network namespace) owns `ip`: only then can a socket bind it."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((ip, 0))
        except OSError:
            return False
    return True


class NeighbourScout(asyncio.DatagramProtocol):
    """One UDP socket on the mesh interface; create with `open()`, always `close()`."""

    def __init__(self, is_local: Callable[[str], bool] = is_local_address) -> None:
        self._transport: asyncio.DatagramTransport | None = None
        self._is_local_ip = is_local
        self._local: dict[str, bool] = {}
        self.own_router: tuple[str, int] | None = None  # the local router's scouting socket
        self._pending: dict[tuple[str, int], bytes] = {}  # neighbours' Hellos heard before it
        self.forwarded = 0

    @classmethod
    async def open(cls, interface: str) -> NeighbourScout:
        address = interface_address(interface)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((address, 0))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(address))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)  # the local router hears it too
            sock.setblocking(False)
            scout = cls()
            await asyncio.get_running_loop().create_datagram_endpoint(lambda: scout, sock=sock)
        except BaseException:
            sock.close()
            raise
        return scout

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.DatagramTransport, transport)

    def round(self) -> None:
        """Ask every router in range to say hello."""
        if self._transport is not None:
            self._transport.sendto(SCOUT_ROUTERS, SCOUTING_GROUP)

    def datagram_received(self, data: bytes, addr: tuple[str | int, int]) -> None:
        if not data or data[0] & ID_MASK != HELLO_ID or self._transport is None:
            return
        source = (str(addr[0]), int(addr[1]))
        if self._is_local(source[0]):
            self.own_router = source
            pending, self._pending = self._pending, {}
            for hello in pending.values():
                self._forward(hello)
        elif self.own_router is None:
            self._pending[source] = data
        else:
            self._forward(data)

    def _forward(self, hello: bytes) -> None:
        assert self._transport is not None and self.own_router is not None
        self._transport.sendto(hello, self.own_router)
        self.forwarded += 1

    def _is_local(self, ip: str) -> bool:
        known = self._local.get(ip)
        if known is None:
            known = self._local[ip] = self._is_local_ip(ip)
        return known

    def error_received(self, exc: Exception) -> None:
        log.debug("neighbour scout: %s", exc)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
