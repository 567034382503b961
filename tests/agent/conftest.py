"""The agent tests' fixtures: each flight-controller adapter the agent contract runs against."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.harness import SimProcess

# The vehicles descend and climb at the top of what their autopilots allow (PX4:
# MPC_LAND_SPEED up to MPC_Z_VEL_MAX_DN 1.5 m/s, MPC_TKO_SPEED up to MPC_Z_VEL_MAX_UP
# 3 m/s; ArduCopter: LAND_SPEED up to 200 cm/s), set as a ground station sets them:
# the same commands and states as at the defaults, in half the flight (landing 10 m
# at PX4's default 0.7 m/s took 14 s of each contract run; ADR 0011).
PX4_BRISK = {"MPC_LAND_SPEED": 1.5, "MPC_TKO_SPEED": 3.0}
ARDUPILOT_BRISK = {"LAND_SPEED": 150}


@pytest.fixture(params=["sim", "mavsdk", "mavsdk-ardupilot"])
def flight_controller(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The `--fc` URL of each adapter under test: the built-in simulated vehicle, and
    real libmavsdk talking UDP to `fleet sim` as a PX4-like and as an ArduCopter-like
    MAVLink vehicle (`--autopilot ardupilot`)."""
    if request.param == "sim":
        yield "sim://?" + "&".join(f"{k}={v}" for k, v in PX4_BRISK.items())
        return
    ardupilot = request.param.endswith("ardupilot")
    params = [f"--param={k}={v}" for k, v in (ARDUPILOT_BRISK if ardupilot else PX4_BRISK).items()]
    sim = SimProcess(tmp_path, extra_args=[*(["--autopilot", "ardupilot"] if ardupilot else []), *params])
    try:
        yield sim.fc_url()
    finally:
        sim.stop()
