"""bus/sockets.py: this process's TCP connections to a host:port, shut down under the
library that holds them (a Zenoh bridge's link to a neighbour)."""

from __future__ import annotations

import socket

from dronefleet.bus.sockets import _address, connection_inodes, shutdown_tcp_to


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
