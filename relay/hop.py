"""The hop that holds (issue 32, relay/chain.py): what the chain's probe has learnt of
it (`Reach`: the longest hop proven, the shortest failed) and what a clean window on a
spot proves when the probe's traffic may have taken another node (`bottleneck`).
Pure code, no I/O and no clock; a local frame in metres around the ground station."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from dronefleet.relay.placement import Point, dist

ORIGIN: Point = (0.0, 0.0)
FLOOR_M = 20.0  # every radio is taken to hold this far (the corpus's shortest is good to 25 m)
GROWTH = 1.5  # a probe with no failed hop yet tries this much beyond the longest proven
CONVERGED = 1.06  # hi / lo this close: the hop is known
MAX_TRIALS = 8  # … or after this many trials


@dataclass
class Reach:
    lo: float = FLOOR_M  # the longest hop proven (a window at most PROVEN_LOSS)
    hi: float | None = None  # the shortest that failed to
    first_tried: bool = False
    trials: int = 0
    holds: float = FLOOR_M  # the longest a window measured to lose at most HOLDING_LOSS (proven ones too)

    @property
    def known(self) -> bool:
        """Bracketed closely enough, or tried often enough (drones standing by the laptop
        can keep the proofs shorter than the trials: the chains then use what was proven)."""
        return (self.hi is not None and self.hi <= self.lo * CONVERGED) or self.trials >= MAX_TRIALS

    def trial(self, first: float | None = None) -> float:
        """The next hop to try: the radio model's (`first`) while nothing failed and it
        is longer than what held, else GROWTH beyond what held, else halfway to what failed."""
        if self.hi is None:
            if first is not None and not self.first_tried and first > self.lo * 1.01:
                self.first_tried = True
                return first
            return self.lo * GROWTH
        return (self.lo + self.hi) / 2

    def held(self, hop: float) -> None:
        self.trials += 1
        self.lo = max(self.lo, hop)
        self.holding(hop)
        if self.hi is not None and self.hi <= self.lo:
            self.hi = self.lo * CONVERGED

    def failed(self, hop: float) -> None:
        self.trials += 1
        if hop > self.lo:
            self.hi = hop if self.hi is None else min(self.hi, hop)

    def holding(self, hop: float) -> None:
        """A window at `hop` lost no more than a 3-s gap allows, proven or not."""
        self.holds = max(self.holds, hop)


def bottleneck(start: tuple[Point, float], others: Sequence[tuple[Point, float]]) -> float:
    """The least, over every path from `start` to the laptop through `others`, of its
    longest hop (3-D): what a clean window at `start` proves the radio holds."""
    nodes = [start, *others, (ORIGIN, 0.0)]
    goal = len(nodes) - 1
    best = [math.inf] * len(nodes)
    best[0] = 0.0
    done = [False] * len(nodes)
    for _ in range(len(nodes)):
        i = min((k for k in range(len(nodes)) if not done[k]), key=lambda k: best[k])
        done[i] = True
        if i == goal:
            break
        for j in range(len(nodes)):
            if not done[j]:
                (a, za), (b, zb) = nodes[i], nodes[j]
                best[j] = min(best[j], max(best[i], math.hypot(dist(a, b), za - zb)))
    return best[goal]
