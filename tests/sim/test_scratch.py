"""Simulations' scratch directories (sim/scratch.py): a killed simulation's is removed
when the next one is made; a live process's, and anything not named so, stay."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from dronefleet.sim.scratch import PREFIX, scratch_dir


def test_the_scratch_of_a_dead_process_goes_and_a_live_ones_stays(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True).stdout.strip()
    gone = tmp_path / f"{PREFIX}{dead}-abc"
    (gone / "world.yml").parent.mkdir()
    (gone / "world.yml").write_text("drones: []\n")
    live = tmp_path / f"{PREFIX}{os.getppid()}-def"  # our parent (pytest's runner): alive
    live.mkdir()
    other = tmp_path / f"{PREFIX}unnamed"
    other.mkdir()
    made = scratch_dir(tmp_path)
    try:
        assert not gone.exists() and live.exists() and other.exists()
        assert Path(made.name).name.startswith(f"{PREFIX}{os.getpid()}-")
    finally:
        made.cleanup()
    assert not Path(made.name).exists()
