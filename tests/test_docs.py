"""The documentation site (issue 54): `mkdocs build --strict` passes (no broken link, no
page left out), its reference pages are generated from the source (every `fleet`
command, every mission verb, the wire messages), and the tutorial's script and commands
run as written."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from dronefleet.mission.script.names import VERBS

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
TUTORIAL = REPO / "docs" / "tutorials" / "first-mission.md"


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
    assert (site / "tutorials" / "first-mission" / "index.html").exists()


def test_the_tutorials_script_and_commands_run_as_written(tmp_path: Path) -> None:
    text = TUTORIAL.read_text()
    scripts = re.findall(r'```python title="([^"]+)"\n(.*?)```', text, re.S)
    assert scripts
    for name, body in scripts:
        (tmp_path / name).write_text(body)
    sessions = re.findall(r"```console\n(.*?)```", text, re.S)
    assert sessions
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
            done = subprocess.run([str(BIN / "fleet"), *command[1:]], cwd=tmp_path, capture_output=True, text=True,
                                  timeout=120, stdin=subprocess.DEVNULL)
            assert done.returncode == 0, (line, done.stdout[-2000:], done.stderr[-2000:])
            for out in expected:
                assert out in done.stdout, (line, out, done.stdout[-2000:])
            ran += 1
    assert ran >= 2
    assert (tmp_path / "out" / "result.json").exists() and (tmp_path / "out" / "paths.png").exists()
