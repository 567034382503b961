"""The radio runs themselves: their own subnets, nothing left after a killed launcher,
no CAP_NET_ADMIN said plainly, and the demo on the radio."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from dronefleet.sim.radio_net import host_lock, leftovers, list_netns
from tests.harness import fleet_command, signal_and_wait
from tests.ports import free_port, free_udp_base
from tests.radio.emulated import RADIO_A, RADIO_B, SIM_STOP_S, fleet_resources, wait_sync

pytestmark = [pytest.mark.integration, pytest.mark.radio]


@RADIO_B
def test_a_killed_launcher_leaves_nothing_after_the_next_start(tmp_path: Path, radio_slot: None) -> None:
    """SIGKILL `fleet sim --radio`: its namespaces stay (and its agents die with it);
    the next radio run removes them before it builds its own."""
    world = tmp_path / "world.yml"
    world.write_text(yaml.safe_dump({"drones": [{"id": "drone01"}]}))
    killed = subprocess.Popen(fleet_command("sim", str(world), "--radio", "--base-port", str(free_udp_base(2) + 1)),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_sync(lambda: f"fleet-{killed.pid}-air" in list_netns(), 30, "the first run's namespaces")
    finally:
        with host_lock():  # no radio run of a parallel test cleans up before we look
            killed.kill()
            killed.wait()
            namespaces, _ = leftovers()
    assert f"fleet-{killed.pid}-air" in namespaces
    second = subprocess.Popen(fleet_command("sim", str(world), "--radio", "--base-port", str(free_udp_base(2) + 1)),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_sync(lambda: f"fleet-{second.pid}-air" in list_netns(), 30, "the second run's namespaces")
        assert fleet_resources(killed.pid) == []
    finally:
        signal_and_wait(second, signal.SIGINT, SIM_STOP_S, "the second fleet sim --radio")
    assert fleet_resources(second.pid) == []


@RADIO_A
def test_radio_runs_started_together_get_their_own_subnets(radio_slot: None) -> None:
    """Parallel radio runs (these tests under xdist, two operators on one laptop) must
    not pick the same /24: the pick holds a lock until the address is taken."""
    from concurrent.futures import ThreadPoolExecutor

    from dronefleet.sim.radio import RadioModel
    from dronefleet.sim.radio_net import RadioNet

    nets = [RadioNet(["d1"], RadioModel(), run=pid) for pid in (os.getpid(), os.getppid())]
    try:
        with ThreadPoolExecutor(2) as pool:
            list(pool.map(RadioNet.up, nets))
        assert nets[0].subnet != nets[1].subnet, [n.subnet for n in nets]
    finally:
        for net in nets:
            net.close()
    assert not [ns for ns in list_netns() if ns.startswith((f"fleet-{os.getpid()}-", f"fleet-{os.getppid()}-"))]


def test_without_net_admin_the_radio_says_so_and_exits_2(tmp_path: Path) -> None:
    world = tmp_path / "world.yml"
    world.write_text(yaml.safe_dump({"drones": [{"id": "drone01"}]}))
    # Drop CAP_NET_ADMIN from the child's bounding and effective sets (setpriv, util-linux).
    result = subprocess.run(["setpriv", "--inh-caps=-all", "--bounding-set=-net_admin", "--",
                             *fleet_command("sim", str(world), "--radio")],
                            capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL)
    assert result.returncode == 2, result
    assert "CAP_NET_ADMIN" in result.stderr


def test_as_root_without_net_admin_the_radio_tests_fail_rather_than_skip(tmp_path: Path) -> None:
    """A root without CAP_NET_ADMIN (a default container) must not pass the suite by
    skipping every radio test (issue 31): one radio test run so fails, and says why."""
    if os.geteuid() != 0:
        pytest.fail("run as root, as CI does")
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "PYTEST_XDIST_WORKER", "PYTEST_ADDOPTS")}
    result = subprocess.run(
        ["setpriv", "--inh-caps=-all", "--bounding-set=-net_admin", "--", sys.executable, "-m", "pytest", "-q",
         "-p", "no:cacheprovider", "-p", "no:randomly", f"{__file__}::test_radio_runs_started_together_get_their_own_subnets"],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, env=env, cwd=tmp_path)
    assert result.returncode == 1, result.stdout[-3000:]
    assert "1 error" in result.stdout and "skipped" not in result.stdout, result.stdout[-3000:]  # its fixture fails
    assert "CAP_NET_ADMIN, which this root lacks" in result.stdout


@RADIO_B
@pytest.mark.slow(80)
@pytest.mark.timeout(480)
def test_the_demo_on_the_radio_traces_the_fire_and_leaves_nothing(tmp_path: Path, radio_slot: None) -> None:
    """`fleet demo --radio`: the fire world with the laptop beside the fire (every point
    of the trace in good range); each agent and sensor in its namespace."""
    from tests.test_demo import run_demo

    world = tmp_path / "near.yml"
    world.write_text(yaml.safe_dump({
        "origin": {"lat": 40.633490, "lon": -8.660815, "alt": 8.2},
        "ground_station": {"lat": 40.633849, "lon": -8.660637},
        "drones": [{"id": "drone01", "lat": 40.633490, "lon": -8.660815, "sensors": ["temperature"]},
                   {"id": "drone02", "lat": 40.633490, "lon": -8.660756}],
        "heat_sources": [{"lat": 40.633849, "lon": -8.660637, "radius": 50, "temp": 60}],
    }))
    out = tmp_path / "demo-out"
    code, stdout, stderr, elapsed = run_demo(
        "--radio", "--until-done", "--world", str(world), "--port", str(free_port()), "--http-port", str(free_port()),
        "--out", str(out), timeout_s=420,
    )
    assert code == 0, f"exit {code} after {elapsed:.0f} s:\n{stdout[-4000:]}\n{stderr[-4000:]}"
    assert "radio: drone01 at 10.231." in stdout and "in namespace fleet-" in stdout
    assert "mission m1 finished: success" in stdout
    result = json.loads((out / "result.json").read_text())
    temperatures = [s["sensors"].get("temperature") for s in result["drones"]["drone01"]["samples"]]
    assert max(t for t in temperatures if t is not None) > 37  # the sensor program in drone01's namespace
    assert "drone01 system connect" in (out / "logs" / "drone01.log").read_text()
    run = re.search(r"in namespace (fleet-\d+-)", stdout).group(1)  # type: ignore[union-attr]
    assert not [ns for ns in list_netns() if ns.startswith(run)]  # all removed on exit (other runs may go on)
