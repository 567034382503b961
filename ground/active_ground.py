"""Which ground is active when several share one mesh (SPEC §14), as pure logic: what a
ground has heard of the others in, whether it is active and with which epoch out. No I/O
and no clock: `ground/ground_peers.py` feeds it from the mesh.

- **The rule.** Every ground applies the same rule to the grounds it hears (their
  liveliness tokens, and what each says of itself): of those whose role is `ground`
  (an `observer` never commands), the highest `priority`, then the lowest `ground_id`.
  Two grounds that hear the same set agree; the one chosen is *active*, the others
  *standby*.
- **Epochs (fencing).** A ground that becomes active takes an epoch one above the
  highest it has heard and says so (`ActiveGround`, published); agents refuse anything
  older than the highest epoch they heard. An active ground that hears a higher epoch
  from another steps down: after a partition heals, the older one gives way by itself,
  and no agent obeys two grounds at once.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

from dronefleet.schemas.grounds import ActiveGround, GroundInfo


def chosen(grounds: Iterable[GroundInfo]) -> str | None:
    """The rule: the ground that should be active among `grounds`, or None (observers only)."""
    candidates = [g for g in grounds if g.role == "ground"]
    if not candidates:
        return None
    return min(candidates, key=lambda g: (-g.priority, g.ground_id)).ground_id


@dataclass(frozen=True)
class Change:
    """What a ground's role became: `active` (with the epoch it took) or `standby`."""

    state: Literal["active", "standby"]
    epoch: int
    why: str
    taken_from: str | None = None  # active: the ground that was active and is gone (its missions go on here)


class Standing:
    """One ground's view of the grounds on the mesh and its own role. Every input
    returns the changes of role it caused, in order (none, one, or a step-down followed
    by a takeover with a newer epoch)."""

    def __init__(self, me: GroundInfo, remembered_epoch: int = 0) -> None:
        self.me = me
        self.heard: dict[str, GroundInfo] = {me.ground_id: me}
        self.highest_epoch = remembered_epoch  # the highest epoch heard from anyone or taken (kept across restarts)
        self._shared = False  # another ground has held our epoch too: take one above it
        self.epoch = 0  # ours while active
        self.active = False
        self.active_id: str | None = None  # who is active as far as we know
        self.epochs: dict[str, int] = {}  # the last epoch each ground said it holds
        self.started = False

    def start(self) -> list[Change]:
        """Decide on what has been heard so far (a ground listens a moment first)."""
        self.started = True
        return self._decide("started")

    def heard_ground(self, info: GroundInfo) -> list[Change]:
        self.heard[info.ground_id] = info
        self.highest_epoch = max(self.highest_epoch, info.epoch_seen)
        self._shared = self._shared or (self.active and info.epoch_held >= self.epoch)
        return self._decide(f"{info.ground_id} appeared")

    def lost_ground(self, ground_id: str) -> list[Change]:
        if ground_id == self.me.ground_id or self.heard.pop(ground_id, None) is None:
            return []
        self.epochs.pop(ground_id, None)
        was_active = self.active_id == ground_id
        if was_active:
            self.active_id = None
        changes = self._decide(f"{ground_id} is gone")
        if was_active:
            changes = [Change(c.state, c.epoch, c.why, ground_id) if c.state == "active" else c for c in changes]
        return changes

    def heard_active(self, said: ActiveGround) -> list[Change]:
        """Another ground says it is active with `said.epoch`. Active with an epoch no
        newer (the same one too: two grounds that each took over alone), this ground
        steps down, then takes over again with a newer epoch if the rule chooses it."""
        if said.ground_id == self.me.ground_id:
            return []
        self.epochs[said.ground_id] = said.epoch
        newest = said.epoch >= self.highest_epoch  # not a late word from a ground that has since stepped down
        self.highest_epoch = max(self.highest_epoch, said.epoch)
        if not self.active:
            if newest:
                self.active_id = said.ground_id
            return []
        if said.epoch < self.epoch:
            return []
        self.active = False
        self.active_id = said.ground_id
        changes = [Change("standby", said.epoch, f"{said.ground_id} is active with epoch {said.epoch} (this one: {self.epoch})")]
        if said.ground_id not in self.heard:  # what it is (its priority) not known yet: decide once it is
            return changes
        return changes + self._decide(f"the rule chooses {self.me.ground_id} over {said.ground_id}")

    def heard_epoch(self, epoch: int, where: str) -> list[Change]:
        """An epoch in use somewhere (an agent refused ours as older): above it, if the
        rule still chooses this ground."""
        if epoch <= self.highest_epoch and not (self.active and epoch >= self.epoch):
            return []
        self.highest_epoch = max(self.highest_epoch, epoch)
        self._shared = self._shared or (self.active and epoch >= self.epoch)
        return self._decide(f"{where} holds epoch {epoch}")

    def _decide(self, why: str) -> list[Change]:
        if not self.started:
            return []
        choice = chosen(self.heard.values())
        if choice == self.me.ground_id and (not self.active or self.epoch < self.highest_epoch or self._shared):
            if self.active:  # another ground held this epoch or a newer one meanwhile: take one above it
                why = f"epoch {self.highest_epoch} was in use"
            self.active, self._shared = True, False
            self.epoch = self.highest_epoch = self.highest_epoch + 1
            self.active_id = self.me.ground_id
            return [Change("active", self.epoch, why)]
        if choice != self.me.ground_id:
            self.active_id = choice
            if self.active:
                self.active = False
                return [Change("standby", self.highest_epoch, why)]
        return []
