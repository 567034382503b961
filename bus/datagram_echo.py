"""Delivery probes below the transport (SPEC §8, ADR 0003 "Link quality").

Zenoh carries everything over TCP (or TLS), which retransmits what the radio loses:
a probe sent as a Zenoh query always arrives while the link lives, a little late,
so a hop losing a quarter of its packets looked perfect until it died. The loss of
the path is therefore measured with datagrams that nothing retransmits (as ETX's
broadcast probes, De Couto et al. 2003): the agent sends a short train of UDP
datagrams to the ground's echo, and the share that comes back is the round-trip
delivery of the hop.

The ground answers on UDP at the port of each TCP/TLS endpoint it listens on (7447
by default), which is the address every agent already dials. The echo answers only
datagrams that start with `MAGIC` and are no longer than `MAX_DATAGRAM`, with the
same bytes (no amplification), and carries nothing else.

`EchoPort` is what the agent's prober needs; `UdpEcho` is it on real packets,
`sim.radio_air.AirEcho` in fast time (the same radio model, no retransmission).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import struct
import threading
import time
from collections.abc import Sequence
from typing import Protocol

from dronefleet.schemas.endpoints import ip_endpoint

log = logging.getLogger(__name__)

MAGIC = b"FLEET-ECHO\x01"
MAX_DATAGRAM = 64
_SEQ = struct.Struct("!Q")
STOP_POLL_S = 0.2  # how soon an echo thread sees that it is to stop
# After its last datagram a train waits for the echoes still out this many times the
# slowest round trip it has seen, at least SETTLE_MIN_S: a lost datagram is not waited
# for a whole period, which would make every report that much older (ADR 0003).
SETTLE_RTTS = 4
SETTLE_MIN_S = 0.2  # a busy laptop (the echo thread, the agent's loop) answers late, not lost
BURST = 10  # datagrams a train sends at once (back to back: well under a millisecond apart)


def settle_s(answered_s: Sequence[float], timeout_s: float) -> float:
    """How long a train waits after its last datagram, given the round trips (s)
    answered so far: `timeout_s` when none is, else a few of the slowest, bounded."""
    if not answered_s:
        return timeout_s
    return min(timeout_s, max(SETTLE_MIN_S, SETTLE_RTTS * max(answered_s)))


class EchoPort(Protocol):
    async def train(self, count: int, spacing_s: float, timeout_s: float) -> list[float | None]:
        """Send `count` datagrams `spacing_s` apart; each one's round trip in ms, or None
        if its echo did not come back in time: within `settle_s` of the last one sent,
        `timeout_s` at most."""
        ...

    def close(self) -> None: ...


def echo_targets(endpoints: Sequence[str]) -> list[tuple[str, int]]:
    """The (host, port) of each IP endpoint that a Zenoh link reaches over TCP or TLS:
    where a ground's echo answers (UDP endpoints are Zenoh's own)."""
    targets = []
    for endpoint in endpoints:
        parsed = ip_endpoint(endpoint)
        if parsed is not None and parsed[0] in ("tcp", "tls") and parsed[2] != 0:
            targets.append((parsed[1], parsed[2]))
    return targets


class _Echoes:
    """The echoes of the train out: when each came back; `all_back` is set when every
    datagram sent has (one future per train, not one per datagram: the agent's CPU)."""

    def __init__(self) -> None:
        self.sent: dict[int, float] = {}  # seq -> when it went
        self.back: dict[int, float] = {}  # seq -> when its echo came
        self.all_back: asyncio.Future[None] | None = None
        self.expected = 0

    def received(self, data: bytes, at: float) -> None:
        if len(data) != len(MAGIC) + _SEQ.size or not data.startswith(MAGIC):
            return
        (seq,) = _SEQ.unpack_from(data, len(MAGIC))
        if seq in self.sent and seq not in self.back:
            self.back[seq] = at
            if len(self.back) == self.expected and self.all_back is not None and not self.all_back.done():
                self.all_back.set_result(None)


class UdpEcho:
    """Datagram trains from this drone to the ground's echo (`targets`: host, port).
    A datagram goes to every target; the first echo counts.

    Each socket is read to empty per wake-up of the loop (asyncio's datagram transport
    reads one datagram per wake-up): a burst's echoes come back together and cost one
    pass of the agent's loop, not five."""

    def __init__(self, sockets: list[socket.socket], targets: list[tuple[str, int]]) -> None:
        self._sockets = sockets
        self._targets = targets
        self._echoes = _Echoes()
        self._seq = 0
        self._loop = asyncio.get_running_loop()
        for sock in sockets:
            self._loop.add_reader(sock.fileno(), self._drain, sock)

    @classmethod
    async def open(cls, endpoints: Sequence[str]) -> UdpEcho | None:
        """An echo client towards the ground endpoints; None if none is an IP endpoint."""
        targets = echo_targets(endpoints)
        if not targets:
            return None
        loop = asyncio.get_running_loop()
        sockets: list[socket.socket] = []
        resolved: list[tuple[str, int]] = []
        for host, port in targets:
            try:
                infos = await loop.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
            except OSError as exc:
                log.warning("link echo: cannot resolve %s: %s", host, exc)
                continue
            family, _, _, _, address = infos[0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
            sock.setblocking(False)
            sockets.append(sock)
            resolved.append((str(address[0]), int(address[1])))
        return cls(sockets, resolved) if sockets else None

    def _drain(self, sock: socket.socket) -> None:
        at = time.monotonic()
        while True:
            try:
                data = sock.recv(MAX_DATAGRAM + 1)
            except BlockingIOError:
                return
            except OSError as exc:  # an ICMP unreachable for a datagram sent: it is lost
                log.debug("echo: %s", exc)
                return  # the rest, if any, on the next wake-up (never a spin on an error)
            self._echoes.received(data, at)

    async def train(self, count: int, spacing_s: float, timeout_s: float) -> list[float | None]:
        """Sends BURST datagrams at a time, BURST spacings apart: a tenth of the event
        loop's wake-ups, and the train still spread over its time."""
        p = self._echoes
        p.sent, p.back, p.expected = {}, {}, count
        p.all_back = self._loop.create_future()
        try:
            for i in range(count):
                if i and i % BURST == 0:
                    await asyncio.sleep(spacing_s * BURST)
                self._seq += 1
                datagram = MAGIC + _SEQ.pack(self._seq)
                p.sent[self._seq] = time.monotonic()
                for sock, target in zip(self._sockets, self._targets, strict=True):
                    try:
                        sock.sendto(datagram, target)
                    except OSError:  # no route right now, or the buffer full: lost
                        pass
            answered = [p.back[seq] - at for seq, at in p.sent.items() if seq in p.back]
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(p.all_back), timeout=settle_s(answered, timeout_s))
            return [(p.back[seq] - at) * 1000.0 if seq in p.back else None for seq, at in p.sent.items()]
        finally:
            p.all_back.cancel()
            p.sent, p.back, p.all_back = {}, {}, None

    def close(self) -> None:
        for sock in self._sockets:
            self._loop.remove_reader(sock.fileno())
            sock.close()
        self._sockets = []


class EchoServer:
    """The ground's echo on UDP at the port of each TCP/TLS endpoint in `listen`, one
    thread per socket: an echo that waited for the ground's event loop (missions,
    the API, the recorder) would count every busy moment of the laptop as radio loss.
    A port that cannot be bound is logged (the agents' quality then comes from their
    Zenoh probes), never fatal: the echo measures, it carries nothing."""

    def __init__(self, listen: Sequence[str]) -> None:
        self._sockets: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        for host, port in echo_targets(listen):
            try:
                family = socket.AF_INET6 if ":" in host else socket.AF_INET
                sock = socket.socket(family, socket.SOCK_DGRAM)
                sock.bind((host, port))
            except OSError as exc:
                log.warning("link echo not served on udp %s:%d: %s", host, port, exc)
                continue
            sock.settimeout(STOP_POLL_S)
            self._sockets.append(sock)
            thread = threading.Thread(target=self._serve, args=(sock,), name=f"echo udp {host}:{port}", daemon=True)
            thread.start()
            self._threads.append(thread)

    @property
    def bound(self) -> int:
        return len(self._sockets)

    def _serve(self, sock: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                data, addr = sock.recvfrom(MAX_DATAGRAM + 1)
                if len(data) <= MAX_DATAGRAM and data.startswith(MAGIC):
                    sock.sendto(data, addr)
            except TimeoutError:
                continue
            except OSError:  # closed, or the sender unreachable for a moment
                if self._stop.is_set():
                    return

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2 * STOP_POLL_S)
        for sock in self._sockets:
            sock.close()
