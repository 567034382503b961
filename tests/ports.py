"""Free ports for the processes a test starts: each xdist worker draws from its own
slice of the range below the kernel's ephemeral ports."""

from __future__ import annotations

import itertools
import os
import random
import socket


def _ephemeral_low() -> int:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def _worker_slice() -> range:
    """This xdist worker's own share of the ports below the kernel's ephemeral range.

    Asking the kernel for port 0 gives a port from the range it also uses for every
    other port-0 listener (each agent's router) and every outgoing connection's local
    port, so a port a test chose and freed (a killed ground restarted on the same port)
    could be taken before it was bound again. Below that range only tests choose, and
    each worker from its own slice."""
    low, high = 15000, _ephemeral_low()  # above the MAVLink ports the sim defaults to (14540…)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    size = (high - low) // count
    return range(low + index * size, low + (index + 1) * size)


_ports = _worker_slice()
_next_port = itertools.count(random.randrange(len(_ports)))  # runs of one worker rarely meet


def free_ports(n: int, kind: socket.SocketKind = socket.SOCK_STREAM) -> int:
    """The first of `n` consecutive ports free on 127.0.0.1 for `kind`, never handed
    out twice by this process while the slice lasts."""
    for _ in range(len(_ports)):
        base = _ports[0] + next(_next_port) % len(_ports)
        if base + n > _ports[-1] + 1:
            continue
        held: list[socket.socket] = []
        try:
            for port in range(base, base + n):
                sock = socket.socket(socket.AF_INET, kind)
                held.append(sock)
                sock.bind(("127.0.0.1", port))
            for _ in range(n - 1):
                next(_next_port)
            return base
        except OSError:
            continue
        finally:
            for sock in held:
                sock.close()
    raise RuntimeError(f"no {n} free ports in {_ports}")


def free_port() -> int:
    return free_ports(1)


def free_udp_base(n: int) -> int:
    """A base port B with B-1 .. B+n-1 free for UDP (the sim's control port and vehicles)."""
    return free_ports(n + 1, socket.SOCK_DGRAM) + 1
