"""The ground's datagram echo and the agent's trains (bus/datagram_echo.py): real UDP
sockets on loopback, unique ports."""

from __future__ import annotations

import asyncio
import socket

from dronefleet.bus.datagram_echo import MAGIC, EchoServer, UdpEcho, echo_targets
from tests.ports import free_udp_base


def test_the_echo_answers_at_the_port_of_each_tcp_or_tls_endpoint() -> None:
    assert echo_targets(["tcp/0.0.0.0:7447", "tls/10.0.0.1:7448", "udp/1.2.3.4:9", "tcp/[::1]:0", "unixsock-stream/x"]) == [
        ("0.0.0.0", 7447), ("10.0.0.1", 7448)]


async def test_a_train_comes_back_from_the_ground_echo_and_is_lost_without_one() -> None:
    port = free_udp_base(1)
    served = EchoServer([f"tcp/127.0.0.1:{port}"])
    echo = await UdpEcho.open([f"tcp/127.0.0.1:{port}"])
    assert echo is not None and served.bound == 1
    try:
        rtts = await echo.train(5, 0.01, timeout_s=1.0)
        assert len(rtts) == 5 and all(r is not None and 0 <= r < 1000 for r in rtts), rtts
    finally:
        served.close()
    try:
        assert await echo.train(3, 0.01, timeout_s=0.2) == [None, None, None]
    finally:
        echo.close()


async def test_the_echo_answers_only_its_own_datagrams_with_the_same_bytes() -> None:
    port = free_udp_base(1)
    served = EchoServer([f"tcp/127.0.0.1:{port}"])
    loop = asyncio.get_running_loop()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setblocking(False)
        s.connect(("127.0.0.1", port))
        try:
            for junk in (b"hello", MAGIC + b"x" * 200):  # not ours, or too long to echo
                await loop.sock_sendall(s, junk)
            probe = MAGIC + b"12345678"
            await loop.sock_sendall(s, probe)
            assert await asyncio.wait_for(loop.sock_recv(s, 1024), 2.0) == probe  # the first and only answer
        finally:
            served.close()


async def test_a_ground_endpoint_that_is_no_ip_endpoint_gives_no_echo() -> None:
    assert await UdpEcho.open(["unixsock-stream//tmp/x.sock"]) is None
