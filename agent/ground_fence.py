"""Which ground an agent obeys when several share the mesh (SPEC §14 fencing), as pure
logic: no I/O, no clock.

A ground that becomes active takes an epoch one above the highest it has seen. Two
grounds can still take the same one: a ground restarted alone reads its last epoch from
its data directory and takes the next, which a standby that took over meanwhile holds
already. An agent that compared epochs alone would obey both. So the fence is the pair:
the agent obeys the newest epoch it has heard, held by the first ground it heard with
it; the same epoch from another ground is refused `stale_ground` like an older one, and
that ground, told the epoch in use, takes one above it (`ground/active_ground.py`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class GroundFence:
    epoch: int = 0  # the newest epoch heard (0: none yet)
    holder: str = ""  # the ground that holds it ("" not known: a ground that named none)

    def admits(self, epoch: int, ground_id: str) -> bool:
        """A command or bundle of `ground_id` at `epoch` (0: a direct client on the mesh,
        never fenced): whether to obey it. Obeyed, it is what is heard."""
        if epoch == 0:
            return True
        if epoch < self.epoch or epoch == self.epoch and ground_id and self.holder and ground_id != self.holder:
            return False
        self.heard(epoch, ground_id)
        return True

    def heard(self, epoch: int, ground_id: str) -> bool:
        """A ground says it is active with `epoch`: True when that is newer than what was heard."""
        if epoch > self.epoch:
            self.epoch, self.holder = epoch, ground_id
            return True
        if epoch == self.epoch and not self.holder:
            self.holder = ground_id
        return False
