"""The command priority rules, table-driven, as pure logic (no event loop)."""

from __future__ import annotations

import pytest

from dronefleet.agent.priority import Active, Decision, Situation, decide, end_state

TAKEOFF = Active("takeoff", "t1")
GOTO = Active("goto", "g1")
MOVE = Active("move", "m1")
LAND = Active("land", "l1")
RETURN = Active("return", "r1")
VELOCITY = Active("velocity_ned", "v1")
QUEUED = Active("goto", "q1")
TURN = Active("turn", "u1")

CASES = [
    # (new command, armed, running, queued) -> decision
    ("takeoff", False, None, None, Decision("refuse", "disarmed")),
    ("goto", False, None, None, Decision("refuse", "disarmed")),
    ("land", False, None, None, Decision("refuse", "disarmed")),
    ("cancel", False, None, None, Decision("refuse", "disarmed")),
    ("velocity_ned", False, None, None, Decision("refuse", "disarmed")),
    ("arm", False, None, None, Decision("start")),
    ("return", False, None, None, Decision("start")),
    ("return", False, LAND, None, Decision("start", ends=(LAND,))),
    ("takeoff", True, None, None, Decision("start")),
    ("goto", True, None, None, Decision("start")),
    ("goto", True, GOTO, None, Decision("start", ends=(GOTO,))),
    ("move", True, GOTO, None, Decision("start", ends=(GOTO,))),
    ("goto", True, MOVE, None, Decision("start", ends=(MOVE,))),
    ("goto", True, TAKEOFF, None, Decision("queue")),
    ("move", True, TAKEOFF, None, Decision("queue")),
    ("goto", True, TAKEOFF, QUEUED, Decision("queue", ends=(QUEUED,))),
    ("goto", True, LAND, None, Decision("refuse", "landing")),
    ("move", True, RETURN, None, Decision("refuse", "returning")),
    ("goto", True, TURN, None, Decision("start", ends=(TURN,))),
    ("goto", True, VELOCITY, None, Decision("start", ends=(VELOCITY,))),
    ("land", True, GOTO, None, Decision("start", ends=(GOTO,))),
    ("land", True, TAKEOFF, QUEUED, Decision("start", ends=(TAKEOFF, QUEUED))),
    ("return", True, TAKEOFF, QUEUED, Decision("start", ends=(TAKEOFF, QUEUED))),
    ("cancel", True, GOTO, None, Decision("start", ends=(GOTO,))),
    ("cancel", True, TAKEOFF, QUEUED, Decision("start", ends=(TAKEOFF, QUEUED))),
    ("cancel", True, None, None, Decision("start")),
    ("turn", True, GOTO, None, Decision("start", ends=(GOTO,))),
    ("takeoff", True, LAND, None, Decision("start", ends=(LAND,))),
    ("velocity_ned", True, VELOCITY, None, Decision("start", ends=(VELOCITY,))),
    ("stop_offboard", True, VELOCITY, None, Decision("start", ends=(VELOCITY,))),
    ("start_offboard", True, GOTO, None, Decision("start", ends=(GOTO,))),
    ("arm", True, GOTO, None, Decision("start")),
    ("disarm", True, LAND, None, Decision("start")),
]


@pytest.mark.parametrize(("name", "armed", "running", "queued", "expected"), CASES)
def test_priority(name: str, armed: bool, running: Active | None, queued: Active | None, expected: Decision) -> None:
    assert decide(name, Situation(armed, running, queued)) == expected


@pytest.mark.parametrize(
    ("name", "state"),
    [("velocity_ned", "stop"), ("attitude", "stop"), ("position_ned", "cancel"), ("goto", "cancel"), ("takeoff", "cancel")],
)
def test_end_state(name: str, state: str) -> None:
    assert end_state(name) == state
