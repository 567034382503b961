"""bus/sockets.py: this process's TCP connections to a host:port, shut down under the
library that holds them (a Zenoh bridge's link to a neighbour); linger turned off on
the sockets a library set it on (Zenoh's links)."""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import time

import pytest

from dronefleet.bus.sockets import LingerOff, _address, _socket_inodes, connection_inodes, linger_off, shutdown_tcp_to
from dronefleet.bus.zenoh_bus import ZenohBus


def test_a_proc_address_reads_as_ip_and_port() -> None:
    assert _address("0100007F:1C8C") == ("127.0.0.1", 7308)
    assert _address("0500E70A:1D48") == ("10.231.0.5", 7496)


def test_the_peer_of_a_connection_shut_down_here_reads_its_end_at_once() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        host, port = server.getsockname()
        server.settimeout(5)
        with socket.create_connection((host, port)) as mine, server.accept()[0] as theirs:
            other = socket.create_connection((host, port))  # a second one, shut down too
            try:
                with server.accept()[0] as third:
                    assert len(connection_inodes(host, port)) == 2
                    assert shutdown_tcp_to(host, port) == 2
                    theirs.settimeout(5)
                    third.settimeout(5)
                    assert theirs.recv(1) == b"" and third.recv(1) == b""  # end of stream, not a timeout
                    assert mine.fileno() >= 0  # the holder's descriptor stays its own to close
            finally:
                other.close()
    assert shutdown_tcp_to("127.0.0.1", 1) == 0


def _lingering(s: socket.socket) -> bool:
    return struct.unpack("ii", s.getsockopt(socket.SOL_SOCKET, socket.SO_LINGER, 8))[0] != 0


def test_closing_a_socket_whose_peer_stopped_reading_returns_at_once_once_linger_is_off() -> None:
    """Zenoh sets a 10 s SO_LINGER on its TCP links; closing one whose data cannot be
    delivered then blocks the closing thread (a router's) until the linger runs out.
    Here the linger is 3 s, the peer never reads and the sender's buffers are full."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        sender = socket.create_connection(server.getsockname())
        with server.accept()[0]:  # accepted, never read
            sender.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 3))
            sender.setblocking(False)
            with contextlib.suppress(BlockingIOError):
                while True:
                    sender.send(b"x" * 65536)
            seen: dict[int, float] = {}
            assert linger_off(seen, now_s=0.0, settle_s=10.0) >= 1
            assert not _lingering(sender)
            began = time.monotonic()
            sender.close()
            assert time.monotonic() - began < 1.5  # with the 3 s linger on, close waited 3 s


def test_a_socket_is_looked_at_until_it_lingered_or_settled() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server, socket.create_connection(server.getsockname()) as mine:
        seen: dict[int, float] = {}
        linger_off(seen, now_s=100.0, settle_s=10.0)  # no linger yet: kept in view
        mine.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 10))  # set after connecting
        assert linger_off(seen, now_s=105.0, settle_s=10.0) == 1 and not _lingering(mine)
        mine.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 10))
        assert linger_off(seen, now_s=106.0, settle_s=10.0) == 0  # done with once turned off
        with socket.create_connection(server.getsockname()) as late:
            linger_off(seen, now_s=200.0, settle_s=10.0)
            late.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 10))
            assert linger_off(seen, now_s=211.0, settle_s=10.0) == 0  # settled without it: no longer looked at
    linger_off(seen, now_s=212.0, settle_s=10.0)
    assert len(seen) < 10  # closed sockets are forgotten


@pytest.mark.integration
async def test_a_zenoh_links_sockets_do_not_linger(endpoint: str) -> None:
    """Zenoh's own TCP links, in this process, lose the linger its build sets."""
    router = await ZenohBus.open("router", listen=[endpoint])
    client = await ZenohBus.open("client", [endpoint])
    try:
        LingerOff.start().sweep()
        sockets = [socket.socket(fileno=os.dup(fd)) for fd in _socket_inodes().values()]
        try:
            assert sockets and not any(_lingering(s) for s in sockets if s.type == socket.SOCK_STREAM)
        finally:
            for s in sockets:
                s.close()
    finally:
        await client.close()
        await router.close()
