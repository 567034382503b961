"""The harness itself: what every test that starts processes relies on."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from tests.conftest import pytest_configure

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
