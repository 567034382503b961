"""How a bench fails: a scenario that failed measures nothing, so the bench says why on
stderr and exits 1 without printing its figure (`make bench` stops at it)."""

from __future__ import annotations

import sys
from pathlib import Path


class ScenarioFailed(SystemExit):
    """Raised where the scenario fails; said at once, so a `finally` that stops processes
    and fails itself cannot hide the reason."""

    def __init__(self, what: str) -> None:
        print(f"bench/{Path(sys.argv[0]).name}: {what}; no figure", file=sys.stderr, flush=True)
        super().__init__(1)
