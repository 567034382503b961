"""This process's own TCP connections, seen from Linux's /proc (ADR 0003).

`shutdown_tcp_to(host, port)` shuts down every TCP connection this process holds to
`host:port`, under whatever library opened it: the peer is sent a FIN at once (the
kernel retransmits it until acknowledged) and reads and writes on it fail here.
Zenoh cannot close one link of a session, and closing a session whose link crosses a
lossy hop takes about 10 s (upstream #2675: `TerminatableTask::terminate` waits that
long for a task stuck in a send); meanwhile the link stays open and unread, and the
router at its other end, a healthy neighbour, waited on every push towards it and went
deaf to the ground for 10.4 s (bench/mesh_corpus.py, a loss ramp beside a freeze).

`LingerOff` turns SO_LINGER off on this process's sockets as they appear. Zenoh 1.10
sets a 10 s linger on every TCP link (`zenoh-link-tcp` `TCP_LINGER_TIMEOUT`, fixed at
its build); on Linux a socket with linger on blocks the thread that closes it until
its unsent data is acknowledged or the linger runs out, whether the socket blocks or
not. A router closing a link over a lossy hop therefore held one of its threads for up
to 10 s, and its forwarding with it (upstream #2350, open; tokio deprecated
`set_linger` for this, tokio-rs/tokio#7751). With linger off, close returns at once
and the kernel still delivers the unsent data and the FIN in the background.
"""

from __future__ import annotations

import ipaddress
import logging
import os
import socket
import stat
import struct
import threading
import time
from pathlib import Path

log = logging.getLogger(__name__)

_ESTABLISHED = "01"


def _address(hex_address: str) -> tuple[str, int]:
    """`0100007F:1C8C` (little-endian IPv4, port) as ('127.0.0.1', 7308)."""
    ip, port = hex_address.split(":")
    return str(ipaddress.IPv4Address(bytes.fromhex(ip)[::-1])), int(port, 16)


def connection_inodes(host: str, port: int, table: str = "/proc/self/net/tcp") -> set[int]:
    """Socket inodes of the established IPv4 TCP connections (of this namespace) to host:port."""
    inodes = set()
    for line in Path(table).read_text().splitlines()[1:]:
        fields = line.split()
        if len(fields) > 9 and fields[3] == _ESTABLISHED and _address(fields[2]) == (host, port):
            inodes.add(int(fields[9]))
    return inodes


def shutdown_tcp_to(host: str, port: int) -> int:
    """Shut down (both ways) this process's TCP connections to host:port; how many."""
    wanted = connection_inodes(host, port)
    done = 0
    for inode, fd in _socket_inodes().items():
        if inode not in wanted:
            continue
        try:
            dup = os.dup(fd)
        except OSError:
            continue
        with socket.socket(fileno=dup) as s:  # closes the duplicate only; the connection is shut down
            try:
                s.shutdown(socket.SHUT_RDWR)
                done += 1
            except OSError:
                pass
    return done


def _socket_inodes() -> dict[int, int]:
    """This process's socket descriptors: inode -> fd.

    `fstat` on the descriptor itself: a quarter of the cost of reading each
    `/proc/self/fd` link, which matters at `LingerOff`'s five sweeps a second."""
    found = {}
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        try:
            st = os.fstat(fd)
        except OSError:
            continue  # closed meanwhile (the listing's own descriptor among them)
        if stat.S_ISSOCK(st.st_mode):
            found[st.st_ino] = fd
    return found


_LINGER = struct.Struct("ii")  # struct linger {int l_onoff; int l_linger;}
_LINGER_OFF = _LINGER.pack(0, 0)


def linger_off(seen: dict[int, float], now_s: float, settle_s: float) -> int:
    """Turn SO_LINGER off on this process's sockets that have it on; how many had it.

    `seen` maps each socket's inode to when it was first seen (updated here). A socket
    is looked at until it had linger on, or for `settle_s` after it appeared: a library
    sets the option once it is connected, which over a lossy hop can be seconds after
    the socket exists."""
    current = _socket_inodes()
    turned = 0
    for inode, fd in current.items():
        first = seen.setdefault(inode, now_s)
        if first < 0 or now_s - first > settle_s:
            continue  # done with: linger turned off, or never set while it settled
        try:
            dup = os.dup(fd)
        except OSError:
            continue
        # A duplicate shares the socket and its options; closing it closes nothing else.
        with socket.socket(fileno=dup) as s:
            try:
                if _LINGER.unpack(s.getsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _LINGER.size))[0]:
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _LINGER_OFF)
                    seen[inode] = -1.0
                    turned += 1
            except OSError:
                pass  # not a socket that has the option, or gone
    for gone in seen.keys() - current.keys():
        del seen[gone]
    return turned


class LingerOff:
    """A daemon thread that keeps linger off on the process's sockets, checking new
    ones every `period_s`. One per process: `LingerOff.start()` is idempotent."""

    _started: LingerOff | None = None
    _lock = threading.Lock()

    def __init__(self, period_s: float, settle_s: float = 10.0) -> None:
        self.period_s = period_s
        self.settle_s = settle_s
        self.turned = 0
        self._seen: dict[int, float] = {}
        self._sweeping = threading.Lock()  # the thread's sweeps and a caller's own
        self._thread = threading.Thread(target=self._run, name="linger-off", daemon=True)

    @classmethod
    def start(cls, period_s: float = 0.2) -> LingerOff:
        with cls._lock:
            if cls._started is None:
                cls._started = cls(period_s)
                cls._started.sweep()  # before the caller opens anything that may close at once
                cls._started._thread.start()
            return cls._started

    def sweep(self) -> int:
        with self._sweeping:
            turned = linger_off(self._seen, time.monotonic(), self.settle_s)
            self.turned += turned
            return turned

    def _run(self) -> None:
        while True:
            time.sleep(self.period_s)
            try:
                self.sweep()
            except OSError as exc:  # /proc unreadable: say so once and stop
                log.warning("cannot keep SO_LINGER off on this process's sockets: %s", exc)
                return
