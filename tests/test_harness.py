"""The test harness itself: what it starts, it stops (issue 31: a child that would not
stop used to leave the others running to load later tests)."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from tests.harness import ChildProcess, stop_all


class Quick(ChildProcess):
    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 0.5) -> int | None:
        return super().stop(sig, timeout_s)


def test_stop_all_stops_every_child_when_one_will_not_stop(tmp_path: Path) -> None:
    stubborn = Quick(["sh", "-c", "trap '' TERM; echo ready; while :; do sleep 0.1; done"], tmp_path / "stubborn.log")
    polite = Quick(["sleep", "60"], tmp_path / "polite.log")
    deadline = time.monotonic() + 10
    while "ready" not in stubborn.output():  # its trap is set: SIGTERM will be ignored
        assert time.monotonic() < deadline, "the stubborn child never started"
        time.sleep(0.01)
    with pytest.raises(AssertionError, match="did not stop within 0.5 s on SIGTERM"):
        stop_all([stubborn, polite])
    assert stubborn.proc is not None and stubborn.proc.poll() == -signal.SIGKILL
    assert polite.proc is not None and polite.proc.poll() == -signal.SIGTERM
