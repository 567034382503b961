"""Each reason a mission sends a command again, alone (mission/lifecycle/send_again.py),
against a sender whose drone is heard, or not, as each test says."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Literal

import pytest

from dronefleet.bus.port import Unreachable
from dronefleet.mission.lifecycle.record import MissionOver
from dronefleet.mission.lifecycle.send_again import (
    DELIVERY_TRIES,
    LinkDropped,
    Step,
    TakeBack,
    TakenBack,
    Unanswered,
    WaitClear,
    deliver,
    steps_for,
)
from dronefleet.schemas.errors import STATE_UNKNOWN, CommandRejected
from dronefleet.schemas.fence import CONFLICT
from dronefleet.schemas.status import DISARMED, RETURNING


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def time_ms(self) -> int:
        return int(self.now * 1000)

    async def sleep(self, seconds: float) -> None:
        self.now += seconds


class Sender:
    """A mission as the steps see it: `heard` says whether the drone's next telemetry comes
    in time; every wait advances the clock by a second."""

    link_grace_s = 10.0
    clear_wait_s = 5.0

    def __init__(self, heard: bool = True, out_of_reach: bool = False) -> None:
        self.clock = Clock()
        self.heard = heard
        self.reach_lost = out_of_reach
        self.lines: list[str] = []
        self.waited: list[str] = []
        self.cancelled: list[str] = []
        self.failsafe_landed: set[str] = set()  # drones whose failsafe flew them home
        self.relaunched: list[str] = []
        self.cancel_refusals: list[Exception] = []  # what the ground answers the next cancels

    def log(self, level: Literal["info", "warn", "error"], message: str) -> None:
        self.lines.append(message)

    def setback(self, cause: str, message: str) -> MissionOver:
        return MissionOver(f"{cause}: {message}")

    def out_of_reach(self, drone_id: str) -> bool:
        return self.reach_lost

    async def heard_again(self, drone_id: str, name: str) -> None:
        self.clock.now += 1
        self.waited.append(f"back {drone_id}")
        self.reach_lost = False

    async def next_heard_within(self, drone_id: str, seconds: float) -> bool:
        self.clock.now += seconds
        return self.heard

    async def next_telemetry(self, drone_id: str) -> None:
        self.clock.now += 1
        self.waited.append(f"telemetry {drone_id}")

    async def cancel(self, drone_id: str) -> None:
        if self.cancel_refusals:
            raise self.cancel_refusals.pop(0)
        self.cancelled.append(drone_id)

    def brought_home(self, drone_id: str) -> bool:
        return drone_id in self.failsafe_landed

    async def relaunch(self, drone_id: str, name: str) -> None:
        self.relaunched.append(drone_id)


def failing(*failures: Exception) -> tuple[Callable[[], Awaitable[str]], list[int]]:
    """A send that fails with each of `failures` in turn, then answers "ok"."""
    sent: list[int] = []

    async def send() -> str:
        sent.append(1)
        if len(sent) <= len(failures):
            raise failures[len(sent) - 1]
        return "ok"
    return send, sent


def unanswered() -> Unreachable:
    return Unreachable("no reply from drone/d1/cmd within 2 s")


def test_unanswered_is_sent_again_each_time_the_drone_is_heard_up_to_its_tries() -> None:
    sender = Sender(heard=True)
    send, sent = failing(*[unanswered()] * (DELIVERY_TRIES - 1))
    assert asyncio.run(deliver(send, [Unanswered(sender, "d1", "goto")])) == "ok"
    assert len(sent) == DELIVERY_TRIES
    assert sum("sending it again" in line for line in sender.lines) == DELIVERY_TRIES - 1
    send, sent = failing(*[unanswered()] * DELIVERY_TRIES)
    with pytest.raises(Unreachable):
        asyncio.run(deliver(send, [Unanswered(Sender(heard=True), "d1", "goto")]))
    assert len(sent) == DELIVERY_TRIES


def test_unanswered_and_unheard_is_tried_for_the_grace_then_ends_link_lost() -> None:
    sender = Sender(heard=False)
    send, sent = failing(*[unanswered()] * 100)
    with pytest.raises(MissionOver, match="link_lost: goto d1: not heard for 10 s"):
        asyncio.run(deliver(send, [Unanswered(sender, "d1", "goto")]))
    assert sender.clock.now > sender.link_grace_s
    assert sum("not heard; trying again" in line for line in sender.lines) == 1  # said once


def test_a_dropped_link_waits_for_the_drone_and_sends_again_without_counting_a_try() -> None:
    sender = Sender(out_of_reach=True)
    send, sent = failing(unanswered(), CommandRejected(409, "state unknown", STATE_UNKNOWN))
    steps: list[Step] = [LinkDropped(sender, "d1", "land"), Unanswered(sender, "d1", "land")]
    assert asyncio.run(deliver(send, steps)) == "ok"
    assert sender.waited == ["back d1", "back d1"] and len(sent) == 3
    assert not any("sending it again" in line for line in sender.lines)


def test_a_spot_another_drone_holds_is_waited_for_then_it_goes() -> None:
    sender = Sender()
    conflict = CommandRejected(409, "drone02 stands there", CONFLICT, other="drone02")
    send, sent = failing(conflict, conflict)
    assert asyncio.run(deliver(send, [WaitClear(sender, "d1", "goto")])) == "ok"
    assert sender.waited == ["telemetry drone02", "telemetry drone02"]
    assert sender.lines == ["d1: goto waits for drone02 to clear the spot (drone02 stands there)",
                            "d1: drone02 cleared the spot, goto goes"]
    send, _ = failing(*[conflict] * 100)
    with pytest.raises(CommandRejected):  # past clear_wait_s: the refusal ends it
        asyncio.run(deliver(send, [WaitClear(Sender(), "d1", "goto")]))


def test_a_failsafe_return_is_stopped_once_and_the_command_taken_back() -> None:
    sender = Sender()
    send, _ = failing(CommandRejected(409, RETURNING, "state"))
    with pytest.raises(TakenBack):
        asyncio.run(deliver(send, [TakeBack(sender, "d1", "goto")]))
    assert sender.cancelled == ["d1"]


def test_a_cancel_the_link_drops_under_is_sent_again_once_the_drone_is_back() -> None:
    """The drone went unknown again just as its failsafe's return was being stopped: the
    cancel waits for it like any command (it used to end the mission cmd_exec "goto
    refused: drone state is unknown")."""
    sender = Sender()
    sender.cancel_refusals.append(CommandRejected(409, "drone state is unknown: no recent telemetry", STATE_UNKNOWN))
    send, _ = failing(CommandRejected(409, RETURNING, "state"))
    with pytest.raises(TakenBack):
        asyncio.run(deliver(send, [TakeBack(sender, "d1", "goto")]))
    assert sender.cancelled == ["d1"] and sender.waited == ["back d1"]


def test_a_drone_its_failsafe_landed_is_taken_up_again_once_and_the_command_taken_back() -> None:
    sender = Sender()
    sender.failsafe_landed.add("d1")
    send, _ = failing(CommandRejected(409, DISARMED))
    with pytest.raises(TakenBack):
        asyncio.run(deliver(send, steps_for(sender, "d1", "goto", take_back=True)))
    assert sender.relaunched == ["d1"] and sender.cancelled == []


def test_a_failure_no_step_takes_is_raised_as_it_came() -> None:
    refused = CommandRejected(409, DISARMED)  # never armed by the mission: no failsafe brought it down
    send, sent = failing(refused)
    with pytest.raises(CommandRejected) as caught:
        asyncio.run(deliver(send, steps_for(Sender(), "d1", "takeoff", wait_clear=True, take_back=True)))
    assert caught.value is refused and len(sent) == 1
