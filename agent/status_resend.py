"""Which statuses an agent sends again when the ground answers after a gap (ADR 0003).

A status is published once, reliably, but "reliable" holds only while the link it left
on stays up: a link that closes takes what it had queued with it, and a ground that
starts after the agent never saw what was published before its subscriptions reached
the drone. The agent cannot know which statuses arrived, so it repeats those that may
not have, and the ground ignores what it already has (SPEC §8). This module is that
policy and nothing else: it is told what was published and when the ground answered a
probe, and answers with what to send again. Times are in ms of the agent's clock.

- Before the first answer from the ground, every command and bundle status is kept
  (up to `KEPT`) and all of them are repeated at that first answer.
- A probe period and a half without an answer is a gap: command statuses published
  from one period before it began are repeated at the answer that ends it — and at
  every answer after another gap, until the link has held for `steady_probes` periods
  in a row (a repeat can go down with a link that closes again at once).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

from dronefleet.schemas.bundles import BundleStatus
from dronefleet.schemas.status import CommandStatus, SystemStatus

KEPT = 64  # statuses kept to repeat: command statuses since a gap, or all before first contact
STEADY_PROBES = 5  # answers in a row after a gap before its repeats count as heard
GAP_PERIODS = 1.5  # probe periods without an answer that make a gap


@dataclass(frozen=True)
class Repeat:
    statuses: list[CommandStatus | BundleStatus]
    why: str


@dataclass(frozen=True)
class Contact:
    gap_ms: int | None  # how long the ground had been silent before this answer; None at the first
    repeats: list[Repeat]  # what to send again, and why


@dataclass
class StatusResend:
    probe_period_ms: int
    steady_probes: int = STEADY_PROBES
    _recent: collections.deque[CommandStatus] = field(default_factory=lambda: collections.deque(maxlen=KEPT))
    # Published before the ground first answered (None after).
    _before_contact: list[CommandStatus | BundleStatus] | None = field(default_factory=list)
    _last_contact_ms: int | None = None
    # Statuses from this time on may not have reached the ground (a gap since, and the
    # contact after it not yet steady).
    _unsure_since_ms: int | None = None
    _steady_from_ms: int = 0

    @property
    def contacted(self) -> bool:
        """The ground has answered at least once."""
        return self._before_contact is None

    def published(self, status: CommandStatus | SystemStatus | BundleStatus) -> None:
        if self._before_contact is not None and isinstance(status, CommandStatus | BundleStatus) \
                and len(self._before_contact) < KEPT:
            self._before_contact.append(status)
        if isinstance(status, CommandStatus):
            self._recent.append(status)

    def contact(self, now_ms: int) -> Contact:
        """The ground answered at `now_ms`: the silence it ended, what to send again and why."""
        repeats = []
        gap_began_ms, self._last_contact_ms = self._last_contact_ms, now_ms
        if self._before_contact is not None:
            unheard, self._before_contact = self._before_contact, None
            repeats.append(Repeat(unheard, "statuses published before the ground answered"))
        period_ms = self.probe_period_ms
        if gap_began_ms is not None and now_ms - gap_began_ms > GAP_PERIODS * period_ms:
            if self._unsure_since_ms is None:  # the first gap since the link last held
                self._unsure_since_ms = gap_began_ms - period_ms
            self._steady_from_ms = now_ms
            since = self._unsure_since_ms
            repeats.append(Repeat([s for s in self._recent if s.timestamp >= since],
                                  "command statuses the ground may have missed"))
        elif self._unsure_since_ms is not None and now_ms - self._steady_from_ms >= self.steady_probes * period_ms:
            self._unsure_since_ms = None  # the link held long enough for the repeats to arrive
        return Contact(None if gap_began_ms is None else now_ms - gap_began_ms, [r for r in repeats if r.statuses])
