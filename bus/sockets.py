"""This process's own TCP connections, seen from Linux's /proc (ADR 0003).

`shutdown_tcp_to(host, port)` shuts down every TCP connection this process holds to
`host:port`, under whatever library opened it: the peer is sent a FIN at once (the
kernel retransmits it until acknowledged) and reads and writes on it fail here.
Zenoh cannot close one link of a session, and closing a session whose link crosses a
lossy hop takes about 10 s (upstream #2675: `TerminatableTask::terminate` waits that
long for a task stuck in a send); meanwhile the link stays open and unread, and the
router at its other end, a healthy neighbour, waited on every push towards it and went
deaf to the ground for 10.4 s (bench/mesh_corpus.py, a loss ramp beside a freeze).
"""

from __future__ import annotations

import ipaddress
import os
import socket
from pathlib import Path

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
    for fd_path in Path("/proc/self/fd").iterdir():
        try:
            target = os.readlink(fd_path)
        except OSError:
            continue  # closed meanwhile
        if not target.startswith("socket:[") or int(target[8:-1]) not in wanted:
            continue
        try:
            dup = os.dup(int(fd_path.name))
        except OSError:
            continue
        with socket.socket(fileno=dup) as s:  # closes the duplicate only; the connection is shut down
            try:
                s.shutdown(socket.SHUT_RDWR)
                done += 1
            except OSError:
                pass
    return done
