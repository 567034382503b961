"""Every radio test needs CAP_NET_ADMIN (a missing one fails as root, never skips) and
stops everything it started, leaving no namespace behind."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from dronefleet.sim.radio_net import has_net_admin
from tests.harness import ChildProcess, stop_all
from tests.radio.emulated import RadioSim, fleet_resources


@pytest.fixture(autouse=True)
def net_admin() -> None:
    if not has_net_admin():
        if os.environ.get("CI") or os.geteuid() == 0:
            # As root (CI runs so) a missing capability is a broken machine, not a reason to skip.
            pytest.fail("the emulated-radio tests need CAP_NET_ADMIN, which this root lacks "
                        "(a container without --cap-add NET_ADMIN?)")
        pytest.skip("needs CAP_NET_ADMIN (run as root)")


@pytest.fixture
def processes(tmp_path: Path, radio_slot: None) -> Iterator[list[ChildProcess]]:
    """Everything a test starts, stopped in reverse; then nothing of the run may remain."""
    started: list[ChildProcess] = []
    yield started
    sims = [p for p in started if isinstance(p, RadioSim)]
    stop_all(reversed(started))  # all of them, even when one is slow to stop
    for sim in sims:
        assert fleet_resources(sim.pid) == [], f"left behind: {fleet_resources(sim.pid)}"
