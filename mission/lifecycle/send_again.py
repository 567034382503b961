"""What a mission does when a command or bundle it sends is not taken: one small step per
reason, each deciding alone whether to send it again (SPEC §5).

`deliver` sends, and on a failure asks each step in turn: a step that recognises the
failure waits for what it needs and answers True (send again), or raises what ends
the mission; one that does not recognise it answers False. A failure no step takes is
raised as it came. Every step keeps its own state for one delivery:

- `LinkDropped`: the drone is out of reach (the mission saw its link go, or the ground
  no longer knows its state): sent again once it is back, however long that takes
  (mission.link_grace_s ends the mission meanwhile, elsewhere).
- `Unanswered`: no answer. Sent again each time the drone is heard, up to
  DELIVERY_TRIES in all (the agent runs one id once); a drone not heard either is tried
  again as it is heard, for mission.link_grace_s, then the mission ends `link_lost`.
- `TakeBack`: the drone's lost-link failsafe is flying it home (or landing it) and a
  goto was refused for it: that is stopped, once, and the command sent again under a
  new id.
- `Relaunch`: the failsafe brought it home and it landed (the command was refused
  "disarmed"): it is armed and taken back up to where it flew, once, and the command
  sent again under a new id.
- `WaitClear`: the target is another drone's spot (409 conflict): sent again each time
  that drone reports, for up to mission.clear_wait_s.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from typing import Literal, Protocol, TypeVar

from dronefleet.bus.clock import Clock
from dronefleet.bus.port import Unreachable
from dronefleet.mission.lifecycle.record import MissionOver
from dronefleet.schemas.errors import STATE_UNKNOWN, CommandRejected
from dronefleet.schemas.fence import CONFLICT
from dronefleet.schemas.status import DISARMED, LANDING, RETURNING

R = TypeVar("R")

DELIVERY_TRIES = 3  # a command with no answer is sent this many times in all
RETRY_WAIT_S = 2.0  # between them: the drone is heard again within this, or counts as unheard


class TakenBack(Exception):  # noqa: N818 - a signal, not an error
    """A drone's failsafe return was stopped: send the command again under a new id (the
    agent answers an id it has seen as it did before)."""


class Sender(Protocol):
    """What the steps need from the mission that sends."""

    @property
    def clock(self) -> Clock: ...

    def log(self, level: Literal["info", "warn", "error"], message: str) -> None: ...
    def setback(self, cause: str, message: str) -> MissionOver: ...
    def out_of_reach(self, drone_id: str) -> bool: ...
    async def heard_again(self, drone_id: str, name: str) -> None: ...
    async def next_heard_within(self, drone_id: str, seconds: float) -> bool: ...
    async def next_telemetry(self, drone_id: str) -> None: ...
    async def cancel(self, drone_id: str) -> None: ...
    def brought_home(self, drone_id: str) -> bool:
        """Whether the drone's lost-link failsafe flew it home (or down) since the mission
        last sent it there itself."""
        ...
    async def relaunch(self, drone_id: str, name: str) -> None:
        """Arm the drone and take it up to the height it flew at before its failsafe, to
        send command `name` again (said in the mission's log)."""
        ...
    @property
    def link_grace_s(self) -> float: ...
    @property
    def clear_wait_s(self) -> float: ...


class Step(Protocol):
    async def after(self, failure: Exception) -> bool:
        """True: send again (after waiting for what this step needs); False: not this
        step's failure. May raise what ends the delivery."""
        ...

    def delivered(self) -> None:
        """The send went through."""
        ...


class _Step:
    """What every step knows: the sender, the drone and the command's name."""

    def __init__(self, sender: Sender, drone_id: str, name: str) -> None:
        self.sender, self.drone_id, self.name = sender, drone_id, name

    def delivered(self) -> None:
        pass


class LinkDropped(_Step):
    async def after(self, failure: Exception) -> bool:
        dropped = (isinstance(failure, Unreachable) and self.sender.out_of_reach(self.drone_id)) or \
                  (isinstance(failure, CommandRejected) and failure.code == STATE_UNKNOWN)
        if dropped:  # the link dropped as it went: not the drone's fault
            await self.sender.heard_again(self.drone_id, self.name)
        return dropped


class Unanswered(_Step):
    def __init__(self, sender: Sender, drone_id: str, name: str) -> None:
        super().__init__(sender, drone_id, name)
        self.attempt = 1
        self.unheard_since: float | None = None

    async def after(self, failure: Exception) -> bool:
        if not isinstance(failure, Unreachable):
            return False
        if self.attempt == DELIVERY_TRIES:
            raise failure
        # A link just back may not carry queries yet: tried again once the drone is
        # heard (or the ground reports it lost), not at once.
        s = self.sender
        if await s.next_heard_within(self.drone_id, RETRY_WAIT_S):
            self.attempt += 1
            self.unheard_since = None
            s.log("warn", f"{self.drone_id}: no answer to {self.name}, sending it again ({self.attempt}/{DELIVERY_TRIES})")
            return True
        now = s.clock.monotonic()
        if self.unheard_since is None:
            self.unheard_since = now
            s.log("warn", f"{self.drone_id}: no answer to {self.name} and not heard; trying again as it is heard")
        if now - self.unheard_since > s.link_grace_s:
            raise s.setback("link_lost", f"{self.name} {self.drone_id}: not heard for {s.link_grace_s:g} s ({failure})")
        return True


class TakeBack(_Step):
    async def after(self, failure: Exception) -> bool:
        if not isinstance(failure, CommandRejected):
            return False
        if failure.reason == RETURNING:
            doing = "flying it home"
        elif failure.reason == LANDING and self.sender.brought_home(self.drone_id):
            doing = "landing it"
        else:
            return False
        self.sender.log("warn", f"{self.drone_id}: its lost-link failsafe is {doing}; stopping that to send "
                                f"{self.name} again, as it hears the ground")
        dropped = LinkDropped(self.sender, self.drone_id, "cancel")
        while True:
            try:
                await self.sender.cancel(self.drone_id)
            except (Unreachable, CommandRejected) as exc:  # the link went again as it was sent
                if not await dropped.after(exc):
                    raise
                continue
            raise TakenBack


class Relaunch(_Step):
    async def after(self, failure: Exception) -> bool:
        if not (isinstance(failure, CommandRejected) and failure.reason == DISARMED
                and self.sender.brought_home(self.drone_id)):
            return False
        await self.sender.relaunch(self.drone_id, self.name)
        raise TakenBack


class WaitClear(_Step):
    def __init__(self, sender: Sender, drone_id: str, name: str) -> None:
        super().__init__(sender, drone_id, name)
        self.give_up = sender.clock.monotonic() + sender.clear_wait_s
        self.waited_for: str | None = None

    async def after(self, failure: Exception) -> bool:
        if not (isinstance(failure, CommandRejected) and failure.code == CONFLICT and failure.other):
            return False
        if self.sender.clock.monotonic() > self.give_up:
            raise failure
        if self.waited_for != failure.other:
            self.waited_for = failure.other
            self.sender.log("info", f"{self.drone_id}: {self.name} waits for {failure.other} to clear the spot "
                                    f"({failure.reason})")
        await self.sender.next_telemetry(failure.other)
        return True

    def delivered(self) -> None:
        if self.waited_for is not None:
            self.sender.log("info", f"{self.drone_id}: {self.waited_for} cleared the spot, {self.name} goes")


async def deliver(send: Callable[[], Awaitable[R]], steps: Sequence[Step]) -> R:
    """Send until it goes through or a failure ends it: the one loop the steps share."""
    while True:
        try:
            reply = await send()
        except (Unreachable, CommandRejected) as failure:
            for step in steps:
                if await step.after(failure):
                    break
            else:
                raise
            continue
        for step in steps:
            step.delivered()
        return reply


def steps_for(sender: Sender, drone_id: str, name: str, *, wait_clear: bool = False,
              take_back: bool = False) -> list[Step]:
    """The steps of one delivery, in the order they are asked."""
    steps: list[Step] = [LinkDropped(sender, drone_id, name), Unanswered(sender, drone_id, name)]
    if take_back:
        steps += [TakeBack(sender, drone_id, name), Relaunch(sender, drone_id, name)]
    if wait_clear:
        steps.append(WaitClear(sender, drone_id, name))
    return steps

