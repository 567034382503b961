"""What a drone installs and how long the agent takes to start importing (issue 13):
the wheel of this tree with the `agent` extra, at the versions of requirements.lock,
in a fresh venv; its size without the venv's own pip/setuptools, and the import time
of what `fleet agent` loads (median of 5 cold-ish runs).

    .venv/bin/python bench/agent_install.py
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
AGENT_IMPORTS = "import fleet.cli, agent.runtime, agent.fc_mavsdk, bus.zenoh_bus"
RUNS = 5


def size_mib(root: Path) -> float:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file() and not p.is_symlink()) / 2**20


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", work / "dist", REPO], check=True)
        (wheel,) = (work / "dist").glob("dronefleet-*.whl")
        venv = work / "venv"
        subprocess.run([sys.executable, "-m", "venv", venv], check=True)
        python = venv / "bin" / "python"
        site = next((venv / "lib").glob("python3*/site-packages"))
        base = size_mib(site)
        subprocess.run([python, "-m", "pip", "install", "-q", "--disable-pip-version-check",
                        "-c", REPO / "requirements.lock", f"{wheel}[agent]"], check=True)
        installed = size_mib(site) - base
        times = []
        for _ in range(RUNS):
            out = subprocess.run(
                [python, "-c", f"import time; t = time.perf_counter(); {AGENT_IMPORTS}; print(time.perf_counter() - t)"],
                check=True, capture_output=True, text=True, cwd=work,
            )
            times.append(float(out.stdout))
        packages = subprocess.run([python, "-m", "pip", "list", "--format=freeze"], check=True, capture_output=True,
                                  text=True).stdout
    print(f"dronefleet[agent]: {installed:.0f} MiB installed ({len(packages.splitlines())} packages with pip/setuptools)")
    print(f"agent import time: median {statistics.median(times) * 1000:.0f} ms over {RUNS} runs "
          f"(min {min(times) * 1000:.0f} ms)")


if __name__ == "__main__":
    main()
