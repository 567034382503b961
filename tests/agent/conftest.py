"""The agent tests' fixtures: each flight-controller adapter the agent contract runs against."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.harness import SimProcess


@pytest.fixture(params=["sim", "mavsdk", "mavsdk-ardupilot"])
def flight_controller(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The `--fc` URL of each adapter under test: the built-in simulated vehicle, and
    real libmavsdk talking UDP to `fleet sim` as a PX4-like and as an ArduCopter-like
    MAVLink vehicle (`--autopilot ardupilot`)."""
    if request.param == "sim":
        yield "sim"
        return
    sim = SimProcess(tmp_path, extra_args=["--autopilot", "ardupilot"] if request.param.endswith("ardupilot") else [])
    try:
        yield sim.fc_url()
    finally:
        sim.stop()
