"""Link quality and lost-link behaviour as pure logic (SPEC §8): probe outcomes in,
scores and decisions out. No I/O and no clock reads: the prober and the agent feed
times and act on what comes back.

Quality is measured, never derived from distance (ADR 0003, "Link quality"). Loss is
the loss of the path below any retransmitting transport: to the ground, each probe
also sends a train of datagrams to the ground's echo (bus/datagram_echo.py) and the
last `DELIVERY_TRAINS` trains give the share that came back (`DeliveryWindow`). To a
neighbour, and to the ground when the drone's traffic crosses other drones (where no
datagram follows it), each probe is a query to the peer's ping queryable and the
window's unanswered share is the loss (`LinkWindow`). Mean RTT, jitter (mean change
between consecutive RTTs) and a score in [0, 1] that falls with loss, to 0 at
`LOSS_UNUSABLE`, and with RTT past what a healthy radio hop shows.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
from msgspec import Meta

WINDOW = 10  # probes per sliding window (one a second: the last 10 s)
RTT_GOOD_MS = 50.0  # RTTs up to this cost nothing
RTT_BAD_MS = 1000.0  # an RTT this long scores zero
# A hop losing this share of its packets has no use left: quality 0, and 0.5 at half
# of it. On a reliable transport a lost packet costs a retransmission (200 ms, then
# doubling): at 10 % loss telemetry at 5 Hz already shows gaps over a second, and a
# relay chain trusts a hop only up to 5 % (relay/chain.py PROVEN_LOSS), where the
# ground starts to warn "link degraded" (ADR 0003).
LOSS_UNUSABLE = 0.1
TRAIN = 50  # datagrams per probe to the ground's echo (1 KB/s)
TRAIN_SPREAD = 0.3  # the share of a period a train is spread over: the report is about its middle
DELIVERY_TRAINS = 1  # trains that the loss to the ground covers: the last one (50 datagrams)

LostLinkAction = Literal["hold", "return", "land", "continue"]


class LostLinkPolicy(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Agent config `lost_link`: what the drone does alone when the ground is gone."""

    timeout_s: Annotated[float, Meta(gt=0, le=3600)] = 5.0
    action: LostLinkAction = "hold"
    return_after_s: Annotated[float, Meta(ge=0, le=86_400)] = 30.0  # hold this long, then return


def quality_score(loss: float, rtt_ms: float | None) -> float:
    """1 for a clean, fast hop; falling linearly with loss to 0 at `LOSS_UNUSABLE`, and
    with RTT from `RTT_GOOD_MS` to 0 at `RTT_BAD_MS`; 0 with nothing answered."""
    if rtt_ms is None:
        return 0.0
    rtt_factor = 1.0 - min(1.0, max(0.0, (rtt_ms - RTT_GOOD_MS) / (RTT_BAD_MS - RTT_GOOD_MS)))
    loss_factor = 1.0 - min(1.0, max(0.0, loss) / LOSS_UNUSABLE)
    return round(loss_factor * rtt_factor, 3)


def _rtt_and_jitter(answered: list[float]) -> tuple[float | None, float | None]:
    rtt = sum(answered) / len(answered) if answered else None
    steps = [abs(b - a) for a, b in itertools.pairwise(answered)]
    jitter = sum(steps) / len(steps) if steps else (0.0 if answered else None)
    return (None if rtt is None else round(rtt, 3)), (None if jitter is None else round(jitter, 3))


@dataclass(frozen=True, slots=True)
class LinkSummary:
    rtt_ms: float | None
    jitter_ms: float | None
    loss: float
    quality: float


class LinkWindow:
    """The last WINDOW probe outcomes to one peer: an RTT in ms, or None if unanswered."""

    def __init__(self, size: int = WINDOW) -> None:
        self._outcomes: deque[float | None] = deque(maxlen=size)

    def add(self, rtt_ms: float | None) -> None:
        self._outcomes.append(rtt_ms)

    def outcomes(self) -> list[float | None]:
        """The window's probe outcomes, oldest first."""
        return list(self._outcomes)

    def summary(self) -> LinkSummary:
        answered = [r for r in self._outcomes if r is not None]
        loss = 1.0 - len(answered) / len(self._outcomes) if self._outcomes else 1.0
        rtt, jitter = _rtt_and_jitter(answered)
        return LinkSummary(rtt_ms=rtt, jitter_ms=jitter, loss=round(loss, 3), quality=quality_score(loss, rtt))


class DeliveryWindow:
    """The last `trains` datagram trains to the ground's echo: each datagram's round
    trip in ms, or None if it or its echo was lost.

    A datagram and its echo each cross the hop once, so the round trip is delivered
    with probability (1 - p)² for a hop losing p of its packets either way; the loss
    reported is that p, `1 - sqrt(delivered share)`: the loss of the packets that
    cross the path, what the radio model (sim/radio.py) gives for a distance."""

    def __init__(self, trains: int = DELIVERY_TRAINS) -> None:
        self._trains: deque[list[float | None]] = deque(maxlen=trains)
        self.echoed = False  # an echo ever came back: the ground serves one

    def add(self, rtts_ms: list[float | None]) -> None:
        self._trains.append(list(rtts_ms))
        self.echoed = self.echoed or any(r is not None for r in rtts_ms)

    def summary(self) -> LinkSummary:
        sent = [r for train in self._trains for r in train]
        answered = [r for r in sent if r is not None]
        delivered = len(answered) / len(sent) if sent else 0.0
        loss = 1.0 - math.sqrt(delivered)
        rtt, jitter = _rtt_and_jitter(answered)
        return LinkSummary(rtt_ms=rtt, jitter_ms=jitter, loss=round(loss, 3), quality=quality_score(loss, rtt))


# ("link_lost", None), ("failsafe", action), ("link_restored", what happened meanwhile)
Decision = tuple[Literal["link_lost", "failsafe", "link_restored"], str | None]


class LostLink:
    """When the ground has been silent for `timeout_s`: lost, act; hold → return later.

    `contact(now)` is any sign of the ground (an answered probe, a command signed by
    the ground); `tick(now, flying)` runs often. Decisions: ("link_lost", None),
    ("failsafe", action), ("link_restored", summary). What was said while the ground
    was gone never reached it, so the restore's summary repeats it: how long, and
    what the drone did.

    As autopilots do it (PX4's data-link check, ArduPilot's GCS failsafe; SPEC §8):
    - armed only once the ground has been heard since the start: an agent on a mesh
      with no ground, commanded directly by a Zenoh client, flies on;
    - acting only in the air: a drone on the ground (or disarmed) reports the loss
      and stays put; if it is flown while the loss lasts, the failsafe acts then;
    - the hold → return time counts from when the hold was taken in the air.

    At the edge of range a link flaps. An outage therefore ends only after contact
    has held steadily for `timeout_s` - no silence longer than `steady_gap_s` (two
    probe periods: one lost probe is tolerated) since the restore. Until then a new
    loss continues the same outage, the hold → return timer keeps counting from the
    hold, and no failsafe repeats.
    """

    def __init__(self, policy: LostLinkPolicy, now: float, steady_gap_s: float = 2.0) -> None:
        self.policy = policy
        self.steady_gap_s = steady_gap_s
        self.last_contact = now
        self.heard = False  # the ground answered once since the start: the failsafe is armed
        self.lost = False
        self.acted: LostLinkAction | None = None
        self.actions: list[LostLinkAction] = []  # taken during this outage
        self._outage_at: float | None = None  # first loss of the open outage
        self._acted_at: float | None = None  # when this outage's first action was taken in the air
        self._restored_at = 0.0
        self._steady = True  # no silence over steady_gap_s since the restore

    def silent(self, now: float) -> bool:
        """No sign of the ground for longer than `steady_gap_s` (two probe periods)."""
        return now - self.last_contact > self.steady_gap_s

    def contact(self, now: float) -> list[Decision]:
        silent_s = now - self.last_contact
        self.last_contact = now
        self.heard = True
        if not self.lost:
            self._steady = self._steady and silent_s <= self.steady_gap_s
            return []
        self.lost = False
        self._restored_at = now
        self._steady = True
        summary = f"after {silent_s:.1f} s without the ground; failsafe: {', '.join(self.actions) or 'none'}"
        return [("link_restored", summary)]

    def acted_alone(self, action: LostLinkAction, now: float) -> None:
        """The drone already did `action` for this outage (a bundle's own link-loss
        policy): no failsafe repeats it, and a hold still turns into a return later."""
        self.acted = action
        self._acted_at = now
        self.actions.append(action)

    def tick(self, now: float, flying: bool) -> list[Decision]:
        p = self.policy
        decisions: list[Decision] = []
        if not self.heard:  # no ground on this mesh yet: nothing to lose
            return decisions
        if not self.lost:
            if now - self.last_contact < p.timeout_s:
                self._steady = self._steady and now - self.last_contact <= self.steady_gap_s
                if self._outage_at is not None and self._steady and now - self._restored_at >= p.timeout_s:
                    # steady again: the outage is over
                    self._outage_at, self._acted_at, self.acted, self.actions = None, None, None, []
                return decisions
            self.lost = True
            if self._outage_at is None:
                self._outage_at = now
            decisions.append(("link_lost", None))
        if not flying:
            return decisions
        if self.acted is None and p.action != "continue":
            self.acted, self._acted_at = p.action, now
        elif self.acted == "hold" and self._acted_at is not None and now - self._acted_at >= p.return_after_s:
            self.acted = "return"
        else:
            return decisions
        self.actions.append(self.acted)
        decisions.append(("failsafe", self.acted))
        return decisions
