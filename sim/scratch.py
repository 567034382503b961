"""Scratch directories of simulations (`fleet sim`, fast-time fields): named after the
process that made them, so the leftovers of one that was killed (SIGKILL runs no
cleanup) are removed the next time one is made, as the emulated radio's namespaces are."""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

from dronefleet.sim.radio_net import pid_alive

PREFIX = "fleet-sim-"
_OWNED = re.compile(rf"{PREFIX}(\d+)-")


def scratch_dir(base: Path | None = None) -> tempfile.TemporaryDirectory[str]:
    """A new scratch directory for this process, after removing those of dead ones."""
    base = base or Path(tempfile.gettempdir())
    for old in base.glob(f"{PREFIX}*"):
        owner = _OWNED.match(old.name)
        if owner is not None and int(owner.group(1)) != os.getpid() and not pid_alive(int(owner.group(1))):
            shutil.rmtree(old, ignore_errors=True)
    return tempfile.TemporaryDirectory(prefix=f"{PREFIX}{os.getpid()}-", dir=base)
