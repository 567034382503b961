"""Which neighbours a drone links through, and when (ADR 0003): the pure decisions of
agent/neighbours.py, kept apart from its I/O and below `sim`, so the fast-time radio (sim/radio_air.py)
follows the same decisions."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

ANSWER_WINDOW = 5  # rounds over which a neighbour's answer rate is taken
GOOD_RATE = 0.8  # a neighbour answering this often is a hop worth relaying through
KEEP_RATE = 0.4  # a bridge already open is kept while its neighbour answers this often
HELD_WINDOW = 10  # an open bridge is also good while it answered GOOD_RATE over this many rounds …
HELD_KEEP_RATE = 0.6  # … and kept, with no good one heard, while it answered this often over them
MAX_BRIDGES = 2
SWAP_AFTER_S = 4.0  # bridges open this long while the ground stayed silent as long give way to others
DIRECT_STEADY_S = 5.0  # the direct link worked this long: the bridges close
START_GRACE_S = 3.0  # at start, the time the direct link gets to come up (a redial every 0.5-1 s)
UNSURE_PROBES = 3  # the last probes to the ground that must have come back clean …
RETRANSMITTED_MS = 150.0  # … each within this (TCP's first retransmission is 200 ms)
STEADY_ROUNDS = 30  # a neighbour heard this many rounds on end is as steady as any (a drone crossing a radio's good range takes less)


class GroundView(Protocol):
    """What an agent makes of the ground from its probes (agent/runtime.py)."""

    def ground_unsure(self) -> bool: ...

    def ground_heard_at(self) -> float:
        """When the ground last answered (monotonic)."""
        ...


def rate(answers: Sequence[bool], window: int = ANSWER_WINDOW) -> float:
    """How often a neighbour answered over the last `window` scouting rounds."""
    last = list(answers)[-window:]
    return sum(last) / len(last) if last else 0.0


def good(answers: Sequence[bool], held: bool) -> bool:
    """A neighbour worth relaying through: answering at least `GOOD_RATE` over the
    last `ANSWER_WINDOW` rounds or, for a bridge already open, over the last
    `HELD_WINDOW`. A scout and its Hello must both cross, so a clean hop (1 % loss)
    misses one round in fifty; two misses in five, a few times in a thousand rounds,
    had closed the only way of a relay chain to the ground for 6 s while it had another
    good neighbour, the next relay out (fast-time corpus). A bridge to a
    neighbour flying off still goes within a round of the two misses: a longer memory
    (7 of 10) kept a worker's hop back down its chain, the fewest-hop way, until it
    was lost (3 s unheard)."""
    return rate(answers) >= GOOD_RATE or (held and rate(answers, HELD_WINDOW) >= GOOD_RATE)


def futile(opened: Mapping[str, float], ground_heard_at: float, now: float) -> set[str]:
    """The open bridges (`opened`: when each opened) that have not brought the ground
    back: open `SWAP_AFTER_S` or longer, and the ground silent as long."""
    if now - ground_heard_at < SWAP_AFTER_S:
        return set()
    return {z for z, at in opened.items() if now - at >= SWAP_AFTER_S}


def choose(answers: Mapping[str, Sequence[bool]], bridged: set[str], futile: set[str] | frozenset[str] = frozenset(),
           heard_rounds: Mapping[str, int] | None = None) -> set[str]:
    """Which neighbours to hold a bridge to, when the drone needs one (pure), from
    each neighbour's answers to the last scouting rounds (oldest first) and how many
    rounds on end each has been heard (`heard_rounds`; a neighbour unheard for
    `ANSWER_WINDOW` rounds starts again from none).

    Good neighbours (`good`) first, those already bridged
    before others (unless `futile`: they did not bring the ground back, and other good
    ones are tried before them — a relay with three good neighbours held the worker and
    the relay beyond, equally good, and not the one toward the laptop, and its chain was
    unheard 30 s; fast-time corpus), then the steadiest (heard longest, up to
    `STEADY_ROUNDS`), then best first, up to `MAX_BRIDGES`. A drone flying through
    the range of a parked one is heard for a few rounds only; a chain's parked relays
    for as long as they are parked: a relay that took bridges to two relays flying
    past it out to their slots, equally good and first by name, had none to the parked
    one below it, and was unheard 10 s while each pair in turn was found futile; its
    worker beyond, 3 s (fast-time corpus). Only when no neighbour is
    good: the open bridges answering at least `KEEP_RATE` over the last rounds or
    `HELD_KEEP_RATE` over `HELD_WINDOW` stay (a drone's only way, 14 % loss, missed
    three scouts of five and was closed: unheard 6 s, relay mode measured in
    tests/relay/test_relay_experiments.py), or else the best ones
    answering that often are tried (a drone in a chain of relays hears the next one up
    and the one it carries about equally, and cannot tell which leads to the ground).
    A fair bridge gives way as soon as a good neighbour is heard: routing takes the
    fewest hops, so a fair hop back down a chain (a worker passing its relays) carried
    the drone's traffic over a lossy link while a clean path was there (fast-time
    corpus, ADR 0006). Never one answering under `KEEP_RATE`: a bridge over a hop that
    bad carried nothing through, and stalled the neighbour's router for seconds
    (bench/mesh_stall.py, frozen: 9.4 s)."""
    rates = {z: rate(a) for z, a in answers.items()}
    steady = {z: min((heard_rounds or {}).get(z, 0), STEADY_ROUNDS) for z in answers}
    best = sorted((z for z, a in answers.items() if good(a, z in bridged)),
                  key=lambda z: (z in futile, z not in bridged, -steady[z], -rates[z], z))
    if best:
        return set(best[:MAX_BRIDGES])
    keep = sorted((z for z in bridged if z in answers and (rates[z] >= KEEP_RATE or rate(answers[z], HELD_WINDOW) >= HELD_KEEP_RATE)),
                  key=lambda z: (-rates[z], z))
    if keep:
        return set(keep[:MAX_BRIDGES])
    heard = sorted((z for z, r in rates.items() if r >= KEEP_RATE), key=lambda z: (-rates[z], z))
    return set(heard[:MAX_BRIDGES])


def unsure(last_rtts_ms: Sequence[float | None]) -> bool:
    """Whether the ground link is in trouble, from the last probes' round trips (None:
    unanswered): one of the last UNSURE_PROBES lost or retransmitted. The drone then
    takes bridges to good neighbours *before* its direct link is lost, so that when its
    lease runs out (2 s of silence) the traffic has a way at once: waiting for the loss
    first, then a round to choose and a handshake, left a worker crossing the edge of
    the laptop's range unheard for 4 s (fast-time corpus, ADR 0006)."""
    return any(r is None or r > RETRANSMITTED_MS for r in list(last_rtts_ms)[-UNSURE_PROBES:])


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

