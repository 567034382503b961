"""The harness itself: what every test that starts processes relies on."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import pytest_configure
from tests.helpers import free_port, free_udp_base

pytestmark = pytest.mark.integration


def test_processes_a_test_starts_stop_on_ctrl_c_even_when_the_run_ignores_it() -> None:
    """`make test &` in a script starts pytest with SIGINT ignored (POSIX, no job
    control); every child would inherit that and outlive the SIGINT that stops it."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # as such a shell leaves it
    try:
        pytest_configure()
        child = subprocess.Popen([sys.executable, "-c", "import time; print('up', flush=True); time.sleep(60)"],
                                 stdout=subprocess.PIPE, text=True)
        try:
            assert child.stdout is not None and child.stdout.readline() == "up\n"
            child.send_signal(signal.SIGINT)
            assert child.wait(timeout=10) == -signal.SIGINT  # KeyboardInterrupt, re-raised as the signal
        finally:
            child.kill()
            child.wait()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_test_ports_are_below_the_kernels_range_and_never_handed_out_twice() -> None:
    """A port the kernel can give to a port-0 listener or an outgoing connection may be
    gone the moment a test frees it (a killed ground restarted on its own port found it
    taken); the ports tests choose come from below that range, this worker's share."""
    low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    ports = [free_port() for _ in range(200)]
    assert len(set(ports)) == len(ports)
    assert all(15000 <= p < low for p in ports), (min(ports), max(ports), low)
    base = free_udp_base(4)
    for port in range(base - 1, base + 4):  # the sim's control port and four vehicles
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", port))
    assert base - 1 not in ports and base + 3 not in ports
