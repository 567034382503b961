"""Fleet installed like real software (issue 13): the wheel, built from this tree and
installed into a fresh venv outside the checkout, runs there. A drone installs
`dronefleet[agent]` only and gets nothing of the ground; an operator's `dronefleet[all]` runs the
demo (`fleet demo --until-done`, as `make demo` does) from the packaged examples, checked
as tests/test_demo.py says. Versions come from requirements.lock."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.ports import free_port
from tests.test_demo import check_demo, run_demo

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[1]
GROUND_ONLY = ("litestar", "uvicorn", "httpx", "matplotlib", "pymavlink")


def run(*args: str | Path, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


UV = Path(sys.executable).parent / "uv"  # pinned in the lock: the Makefile installs with it too


def installed(venv: Path) -> set[str]:
    listed = run(UV, "pip", "freeze", "--python", venv / "bin" / "python", cwd=venv)
    return {line.split("==")[0].lower() for line in listed.stdout.splitlines()}


@pytest.mark.slow(100)
@pytest.mark.timeout(900)
def test_the_wheel_installs_by_role_and_runs_outside_the_checkout(tmp_path: Path) -> None:
    built = run(UV, "build", "--wheel", "--quiet", "--out-dir", tmp_path / "dist", REPO, cwd=tmp_path)
    assert built.returncode == 0, built.stderr
    (wheel,) = (tmp_path / "dist").glob("dronefleet-*.whl")
    # One top-level import package under a name free on PyPI (SPEC §1): nothing else
    # lands in site-packages beside it, and every folder of the repository is inside.
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
    assert {n.split("/")[0] for n in names if ".dist-info/" not in n} == {"dronefleet"}, names
    assert {n.split("/")[1] for n in names if n.count("/") > 1 and ".dist-info/" not in n} == {
        "agent", "bus", "examples", "ground", "mission", "relay", "schemas", "sim"}, names
    venv = tmp_path / "venv"
    made = run(UV, "venv", "--quiet", "--python", sys.executable, venv, cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    # Built, made and installed with uv (what pip resolves from the same wheel's
    # metadata, in a quarter of pip's time for matplotlib, Litestar and the rest),
    # without compiling every installed module's bytecode (pip's default): the demo
    # compiles only what it imports, 11 s less of the suite's CPU.
    install: list[str | Path] = [UV, "pip", "install", "--quiet", "--python", venv / "bin" / "python",
                                 "-c", REPO / "requirements.lock"]
    fleet = venv / "bin" / "fleet"
    work = tmp_path / "work"  # not the checkout: nothing can come from the source tree
    work.mkdir()

    # A drone: the agent extra, and nothing of the ground.
    agent = run(*install, f"{wheel}[agent]", cwd=work)
    assert agent.returncode == 0, agent.stderr
    assert not installed(venv) & set(GROUND_ONLY), f"dronefleet[agent] pulled {installed(venv) & set(GROUND_ONLY)}"
    helped = run(fleet, "agent", "--help", cwd=work)
    assert helped.returncode == 0 and "--mesh-interface" in helped.stdout, helped.stderr
    ground = run(fleet, "ground", "--http-port", "0", cwd=work, timeout=60)
    assert ground.returncode == 1, ground
    assert "pip install 'dronefleet[ground]'" in ground.stderr and "Traceback" not in ground.stderr, ground.stderr

    # The operator's laptop: everything; the demo finds its world and script in the package.
    everything = run(*install, f"{wheel}[all]", cwd=work)
    assert everything.returncode == 0, everything.stderr
    located = run(venv / "bin" / "python", "-c", "from dronefleet import examples; print(examples.DIR)", cwd=work)
    assert located.stdout.strip().startswith(str(venv)), located
    out = work / "demo-out"
    zenoh_port, http_port = free_port(), free_port()
    code, stdout, stderr, elapsed = run_demo("--until-done", "--port", str(zenoh_port), "--http-port", str(http_port),
                                             "--out", str(out), timeout_s=420, fleet=[str(fleet)], cwd=work)
    assert code == 0, f"exit {code} after {elapsed:.0f} s:\n{stdout[-3000:]}\n{stderr[-3000:]}"
    check_demo(stdout, out, zenoh_port, http_port)
