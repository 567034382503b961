"""The agent tests' fixtures: each flight-controller adapter the agent contract runs against."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.harness import SimProcess

# The ArduCopter-like vehicle descends briskly (LAND_SPEED up to 200 cm/s, WPNAV_SPEED_DN
# up to 500) and disarms 3 s after touchdown (DISARM_DELAY, 10 by default), set as a
# ground station sets them: the same commands and states as at the defaults, in less
# flight and less waiting (ADR 0011). Real ArduCopter SITL flies the contract at its
# defaults (bench/autopilot_contract.py). The PX4-like one flies PX4's defaults, as a user
# flies them (landing at 0.7 m/s): every timing window an autopilot's lag opens is
# there as in the field. The built-in sim flies PX4's brisk settings.
PX4_BRISK = {"MPC_LAND_SPEED": 1.5, "MPC_TKO_SPEED": 3.0}
ARDUPILOT_BRISK = {"LAND_SPEED": 150, "WPNAV_SPEED_DN": 300, "DISARM_DELAY": 3}


@pytest.fixture(params=["sim", "mavsdk", "mavsdk-ardupilot"])
def flight_controller(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The `--fc` URL of each adapter under test: the built-in simulated vehicle, and
    real libmavsdk talking UDP to `fleet sim` as a PX4-like vehicle at PX4's default
    parameters and as an ArduCopter-like one (`--autopilot ardupilot`)."""
    if request.param == "sim":
        yield "sim://?" + "&".join(f"{k}={v}" for k, v in PX4_BRISK.items())
        return
    ardupilot = request.param.endswith("ardupilot")
    params = [f"--param={k}={v}" for k, v in ARDUPILOT_BRISK.items()] if ardupilot else []
    sim = SimProcess(tmp_path, extra_args=[*(["--autopilot", "ardupilot"] if ardupilot else []), *params])
    try:
        yield sim.fc_url()
    finally:
        sim.stop()
