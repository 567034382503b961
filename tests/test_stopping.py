"""A `fleet` process told to stop (SIGTERM) ends: its clean-up runs, and one that hangs
is ended after the command's grace with every thread's stack printed (cli_kit.run_async)."""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

import pytest

from tests.harness import ChildProcess

CHILD = """
import asyncio, threading
from dronefleet.cli_kit import run_async

async def main():
    print("ready", flush=True)
    try:
        await asyncio.sleep(60)
    finally:
        print("cleaning up", flush=True)
        if {hangs}:
            threading.Event().wait()  # a clean-up that never returns (a native call, say)

run_async(main(), stop_grace_s=0.5)
"""


def started(tmp_path: Path, hangs: bool) -> ChildProcess:
    child = ChildProcess([sys.executable, "-c", CHILD.format(hangs=hangs)], tmp_path / "child.log")
    deadline = time.monotonic() + 20
    while "ready" not in child.output():
        assert child.proc.poll() is None, child.output()
        assert time.monotonic() < deadline, "the child never started"
        time.sleep(0.01)
    return child


@pytest.mark.parametrize("hangs", [False, True])
def test_a_process_told_to_stop_ends_and_says_where_a_hung_clean_up_hung(tmp_path: Path, hangs: bool) -> None:
    child = started(tmp_path, hangs)
    code = child.stop(timeout_s=10)
    out = child.output()
    assert "cleaning up" in out
    if hangs:
        assert code == 1, out
        assert "Timeout (0:00:00.500000)!" in out, out
        assert re.search(r'File "<string>", line \d+ in main', out), out  # the stack of the thread that hung
    else:
        assert code == 0, out
        assert "Timeout" not in out, out
