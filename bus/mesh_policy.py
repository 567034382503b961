"""Which neighbours a drone links through, and when (ADR 0003): the pure decisions of
agent/neighbours.py, kept apart from its I/O (and below `sim`, so the fast-time radio
can follow them too; ADR 0003 says why it does not yet)."""

from __future__ import annotations

ANSWER_WINDOW = 5  # rounds over which a neighbour's answer rate is taken
GOOD_RATE = 0.8  # a neighbour answering this often is a hop worth relaying through
KEEP_RATE = 0.4  # a bridge already open is kept while its neighbour answers this often
MAX_BRIDGES = 2
DIRECT_STEADY_S = 5.0  # the direct link worked this long: the bridges close
START_GRACE_S = 3.0  # at start, the time the direct link gets to come up (a redial every 0.5-1 s)


def choose(rates: dict[str, float], bridged: set[str]) -> set[str]:
    """Which neighbours to hold a bridge to, when the drone needs one (pure).

    Open bridges are kept while their neighbour answers at least `KEEP_RATE`; new ones
    go to neighbours answering `GOOD_RATE`, best first, up to `MAX_BRIDGES`; when no
    neighbour is good and none is kept, the best ones answering at least `KEEP_RATE`
    (a drone in a chain of relays hears the next one up and the one it carries about
    equally, and cannot tell which leads to the ground). Never one answering less: a
    bridge over a hop that bad carried nothing through, and stalled the neighbour's
    router for seconds (bench/mesh_stall.py, frozen: 9.4 s)."""
    keep = sorted((z for z in bridged if rates.get(z, 0.0) >= KEEP_RATE), key=lambda z: -rates[z])
    good = sorted((z for z, r in rates.items() if r >= GOOD_RATE and z not in keep), key=lambda z: (-rates[z], z))
    chosen = (keep + good)[:MAX_BRIDGES]
    if not chosen:
        heard = sorted((z for z, r in rates.items() if r >= KEEP_RATE), key=lambda z: (-rates[z], z))
        chosen = heard[:MAX_BRIDGES]
    return set(chosen)


class NeedWatch:
    """Whether the drone needs bridges (pure; times are monotonic): from the moment its
    direct link to the ground stops working until that link has worked again for
    `steady_s`. A direct link that has not come up in the first `grace_s` after start
    counts as not working."""

    def __init__(self, start: float, steady_s: float = DIRECT_STEADY_S, grace_s: float = START_GRACE_S) -> None:
        self.steady_s = steady_s
        self.grace_until = start + grace_s
        self.needed = False
        self._working_since: float | None = None

    def update(self, direct_works: bool, now: float) -> bool:
        if direct_works:
            if self._working_since is None:
                self._working_since = now
            if self.needed and now - self._working_since >= self.steady_s:
                self.needed = False
        else:
            self._working_since = None
            if now >= self.grace_until or self.needed:
                self.needed = True
        return self.needed
