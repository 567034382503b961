"""The documentation site (issue 54): `mkdocs build --strict` passes (no broken link, no
page left out), its reference pages are generated from the source (every `fleet`
command, every mission verb, the wire messages), and the tutorial's script and commands
run as written."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from dronefleet.mission.script.names import VERBS

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.mark.slow(8)
def test_the_site_builds_strict_with_its_reference_generated_from_the_source(tmp_path: Path) -> None:
    site = tmp_path / "site"
    built = subprocess.run([str(BIN / "mkdocs"), "build", "--strict", "--quiet", "--site-dir", str(site)], cwd=REPO,
                           capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL,
                           env={"PATH": str(BIN) + ":/usr/bin:/bin", "NO_MKDOCS_2_WARNING": "1"})
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    cli = (site / "reference" / "cli" / "index.html").read_text()
    for command in ("fleet agent", "fleet ground", "fleet sim", "fleet mission simulate", "--observer", "--autopilot"):
        assert command in cli, command
    dsl = (site / "reference" / "dsl" / "index.html").read_text()
    missing = [v for v in VERBS if f'id="dronefleet.mission.script.dsl.Verbs.{v}"' not in dsl]
    assert not missing, missing
    wire = (site / "reference" / "wire" / "index.html").read_text()
    for field in ("flight_mode", "rel_alt", "command_id", "on_link_loss", "quality"):
        assert field in wire, field
    api = (site / "reference" / "http-api" / "index.html").read_text()
    for endpoint in ("#post-dronedrone_idcmd", "#get-missionmission_id", "#get-ground", "Input parameters"):
        assert endpoint in api, endpoint
    config = (site / "reference" / "config" / "index.html").read_text()
    for key in ("lost_link.action", "dashboard.tiles", "link_degraded_below", "heat_sources[].radius", "radio.good_m"):
        assert f"<code>{key}</code>" in config, key
    for tutorial in ("first-mission", "team-mission"):
        assert (site / "tutorials" / tutorial / "index.html").exists(), tutorial


TUTORIALS = sorted((REPO / "docs" / "tutorials").glob("*.md"))
LIVE = {"live-fleet": 60}  # tutorials that fly real processes in real time: their `slow` estimate


@pytest.mark.parametrize("tutorial", [pytest.param(t, id=t.stem, marks=[pytest.mark.slow(LIVE[t.stem])] if t.stem in LIVE else [])
                                      for t in TUTORIALS])
def test_the_tutorials_files_and_commands_run_as_written(tutorial: Path, tmp_path: Path) -> None:
    """Every file a tutorial has the reader save (a block with a title) is saved, then
    every `$ fleet …` of its console blocks runs there and prints the lines under it; a
    command ending in `&` keeps running in the background (a ground, simulated drones)
    until the tutorial's commands are done, then is stopped."""
    text = tutorial.read_text()
    files = re.findall(r'```(?:python|yaml) title="([^"]+)"\n(.*?)```', text, re.S)
    assert files
    for name, body in files:
        (tmp_path / name).write_text(body)
    sessions = re.findall(r"```console\n(.*?)```", text, re.S)
    assert sessions
    background: list[subprocess.Popen[bytes]] = []
    try:
        ran = _run_sessions(sessions, tmp_path, background)
    finally:
        for proc in background:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
        for proc in background:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    assert ran >= 2


def _ports() -> tuple[list[str], list[str], dict[str, str]]:
    """What the tutorials' commands get on top of what they say, so that the suite's
    parallel tests never meet on the default ports (7447, 8001, MAVLink from 14540):
    `fleet ground`'s router and API, `fleet sim`'s vehicles and agents, and every other
    command's ground (FLEET_URL)."""
    from tests.ports import free_port, free_udp_base

    zenoh, http, mavlink = free_port(), free_port(), free_udp_base(4)
    return ([f"--listen=tcp/127.0.0.1:{zenoh}", f"--http-port={http}"],
            [f"--connect=tcp/127.0.0.1:{zenoh}", f"--base-port={mavlink}"],
            {**os.environ, "FLEET_URL": f"http://127.0.0.1:{http}"})


def _run_sessions(sessions: list[str], tmp_path: Path, background: list[subprocess.Popen[bytes]]) -> int:
    ground_ports, sim_ports, env = _ports()
    ran = 0
    for session in sessions:
        lines = session.splitlines()
        for i, line in enumerate(lines):
            if not line.startswith("$ "):
                continue
            expected = []
            for out in lines[i + 1:]:
                if out.startswith("$ "):
                    break
                expected.append(out)
            command = line[2:].split()
            assert command[0] == "fleet", line
            args = [*command[1:]]
            in_background = args[-1] == "&"
            if in_background:
                args.pop()
            args += ground_ports if args[0] == "ground" else sim_ports if args[0] == "sim" else []
            if in_background:
                log = open(tmp_path / f"background-{len(background)}.log", "wb")  # noqa: SIM115 - the process keeps it
                background.append(subprocess.Popen([str(BIN / "fleet"), *args], cwd=tmp_path, stdout=log, env=env,
                                                   stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True))
                continue
            done = subprocess.run([str(BIN / "fleet"), *args], cwd=tmp_path, capture_output=True, text=True,
                                  timeout=120, stdin=subprocess.DEVNULL, env=env)
            assert done.returncode == 0, (line, done.stdout[-2000:], done.stderr[-2000:])
            for out in expected:
                assert out in done.stdout, (line, out, done.stdout[-2000:])
            ran += 1
        out_dirs = re.findall(r"--out (\S+)", session)
        for out_dir in out_dirs:
            assert (tmp_path / out_dir / "result.json").exists() and (tmp_path / out_dir / "paths.png").exists()
    return ran


async def test_the_api_page_is_drawn_from_what_a_live_ground_serves(tmp_path: Path) -> None:
    """docs/reference/openapi.json is the ground's `GET /openapi.json` as it is now: a
    route, parameter or schema changed without it fails here (refresh it as the page says)."""
    import httpx

    from tests.harness import GroundProcess

    ground = GroundProcess(tmp_path)
    try:
        await ground.ready()
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            live = (await http.get("/openapi.json")).json()
    finally:
        ground.stop()
    documented = json.loads((REPO / "docs" / "reference" / "openapi.json").read_text())
    assert live == documented, "docs/reference/openapi.json is stale: refresh it (docs/reference/http-api.md)"
