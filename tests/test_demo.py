"""`fleet demo --until-done`, run as CI runs it (`make demo ARGS=--until-done`): a real
subprocess with its ground, three agents and the fire-tracing mission over real Zenoh.
`run_demo` starts it, `check_demo` judges a run on the default world (the suite flies
that once, from the installed wheel: tests/test_install.py; the radio's demo is
tests/radio/'s).

The demo runs in its own process group, so whatever happens the test can make sure no
agent outlives it.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import mercantile
import pytest

from dronefleet.ground.tile_archive import TileArchive
from tests.ports import free_port

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[1]
PLOTS = ("paths.png", "altitude.png", "battery.png", "distances.png")


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def run_demo(*args: str, timeout_s: float, fleet: list[str] | None = None, cwd: Path = REPO) -> tuple[int, str, str, float]:
    """`python -m dronefleet demo ARGS` (or `FLEET demo ARGS`) with stdin closed: (exit
    code, stdout, stderr, seconds). Past the timeout it gets SIGTERM (its clean stop),
    then its whole group SIGKILL."""
    started = time.monotonic()
    proc = subprocess.Popen(
        [*(fleet or [sys.executable, "-m", "dronefleet"]), "demo", *args],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=cwd, start_new_session=True,
    )
    try:
        try:
            stdout, stderr = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGTERM)
            try:
                stdout, stderr = proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                stdout, stderr = proc.communicate()
            pytest.fail(f"fleet demo {' '.join(args)} still running after {timeout_s:g} s:\n{stdout[-4000:]}\n{stderr[-4000:]}")
        elapsed = time.monotonic() - started
        # The demo stopped its agents itself: nothing of its process group is left.
        deadline = time.monotonic() + 5
        while _group_alive(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _group_alive(proc.pid), "an agent of the demo outlived it"
        return proc.returncode, stdout, stderr, elapsed
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


def check_demo(stdout: str, out: Path, zenoh_port: int, http_port: int) -> None:
    """What `fleet demo --until-done` on the default world must show and leave in `out`.
    tests/test_install.py runs the demo from the installed wheel, outside the checkout,
    and checks it with this (one demo run in the suite: the wheel's is the stricter)."""
    assert f"http://127.0.0.1:{http_port}/" in stdout
    assert f"fleet sub 'drone/**' --connect tcp/127.0.0.1:{zenoh_port}" in stdout
    assert "all drones ready: drone01, drone02, drone03" in stdout
    assert "Assigned drone01 (a drone with temperature)" in stdout
    assert "tracing the 40 °C perimeter" in stdout
    assert "mission m1 finished: success" in stdout
    assert "drone01 active |" in stdout  # the periodic status line
    # The dashboard's map: the world drawn as tiles in OUT (no tile server, no internet).
    assert f"map: {out / 'map.pmtiles'}" in stdout
    archive = TileArchive(out / "map.pmtiles")
    try:
        south, west, north, east = archive.summary()["bounds"]
        assert (archive.min_zoom, archive.max_zoom) == (15, 18)
        spawn = mercantile.tile(-8.660815, 40.633490, 18)  # the fire world's drone01
        assert south < 40.633490 < north and west < -8.660815 < east and archive.tile(18, spawn.x, spawn.y)
    finally:
        archive.close()
    for name in (*PLOTS, "result.json", "ground.log", "logs/drone01.log"):
        assert (out / name).stat().st_size > 0, name

    result = json.loads((out / "result.json").read_text())
    assert result["mission"]["status"] == "finished" and result["mission"]["cause"] == "success"
    assert set(result["drones"]) == {"drone01", "drone02", "drone03"}
    samples = result["drones"]["drone01"]["samples"]
    temperatures = [s["sensors"]["temperature"] for s in samples if s["sensors"].get("temperature") is not None]
    assert max(temperatures) > 37
    assert max(s["rel_alt"] for s in samples) > 2.5  # it flew (takeoff to 3 m)
    assert samples[-1]["rel_alt"] < 1  # and came home
    # Every drone is sampled at the same instants, so the plots can pair them.
    assert {s["t_s"] for s in samples} & {s["t_s"] for s in result["drones"]["drone02"]["samples"]}


@pytest.mark.timeout(120)
def test_demo_with_its_http_port_taken_fails_fast_naming_the_port(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, stdout, stderr, elapsed = run_demo(
            "--until-done", "--port", str(free_port()), "--http-port", str(port), "--out", str(tmp_path / "out"),
            timeout_s=60,
        )
    assert code != 0, stdout
    assert f"cannot serve HTTP on 127.0.0.1:{port}" in stderr and "--http-port" in stderr, stderr
    assert "Traceback" not in stderr
    # It failed before it flew anything: no drone was started, no mission submitted.
    assert "all drones ready" not in stdout and "mission m1" not in stdout, stdout
    assert not (tmp_path / "out" / "logs" / "drone01.log").exists()


SHORT_GAS = """
gas = field_sensors(type="gas")
while not gas:
    sleep(0.5 * s)
    gas = field_sensors(type="gas")
alarm = gas[0]
d = assign(sensor="gas", role="survey", near=alarm)
print(f"alarm {alarm.id} {alarm.value.co_ppm:.0f} ppm; {d.id} reads {d.sensor.gas.co_ppm:.1f} ppm")
"""


@pytest.mark.timeout(240)
def test_demo_with_another_world_and_mission_runs_its_declared_sensors_and_field_sensors(tmp_path: Path) -> None:
    """`fleet demo --world examples/worlds/gas_alarm.yml --mission …`: the agents (real
    processes) declare the world's kinds, roles and sensors, the world's field sensor is
    on the mesh, and the mission reads both; result.json and the plots have them."""
    script = tmp_path / "gas.py"
    script.write_text(SHORT_GAS)
    out = tmp_path / "out"
    zenoh_port, http_port = free_port(), free_port()
    code, stdout, stderr, _ = run_demo("--world", str(REPO / "examples/worlds/gas_alarm.yml"), "--mission", str(script),
                                       "--until-done", "--out", str(out), "--port", str(zenoh_port),
                                       "--http-port", str(http_port), timeout_s=200)
    assert code == 0, stdout + stderr
    assert "mission m1 submitted: gas.py" in stdout
    assert "alarm gas07 195 ppm; drone02 reads 2.0 ppm" in stdout, stdout
    ground = (out / "ground.log").read_text()
    assert "drone02 - Declares kind multicopter, roles survey, sensors gas (co_ppm)" in ground, ground
    assert "drone04 - Declares kind multicopter, roles auxiliary, sensors none declared" in ground, ground
    result = json.loads((out / "result.json").read_text())
    assert result["field_sensors"]["gas07"]["readings"][0]["value"]["co_ppm"] > 50
    assert any(s["sensors"].get("gas", {}).get("co_ppm") == 2.0 for s in result["drones"]["drone02"]["samples"])
    assert (out / "sensors.png").stat().st_size > 0
