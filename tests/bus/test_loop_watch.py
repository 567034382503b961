"""A blocked event loop is reported with where it is stuck (bus/loop_watch.py)."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from dronefleet.bus.loop_watch import LoopWatch


def block_the_loop_for(seconds: float) -> None:
    time.sleep(seconds)  # the stall under test: a blocking call on the loop's thread


async def test_a_blocked_loop_is_reported_with_its_stack_and_how_long(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "dronefleet.bus.loop_watch")
    watch = LoopWatch("test", threshold_s=0.5, period_s=0.1)

    def said(words: str) -> list[str]:
        return [r.getMessage() for r in caplog.records if words in r.getMessage()]

    try:
        await asyncio.sleep(0.3)  # the observed span: three beats of a loop turning normally
        assert caplog.records == []
        block_the_loop_for(1.2)
        for _ in range(500):  # wait (10 s at most) for the beat after the stall to say how long it was
            if said("turned again after"):
                break
            await asyncio.sleep(0.02)
    finally:
        watch.close()
    messages = [r.getMessage() for r in caplog.records]
    stuck = [m for m in messages if "has not turned" in m]
    assert len(stuck) == 1 and "block_the_loop_for" in stuck[0], messages
    again = [m for m in messages if "turned again after" in m]
    assert len(again) == 1, messages
    # At least the 1.2 s block less one 0.1 s beat period; the upper bound only catches nonsense.
    assert 1.05 <= watch.longest_s < 5.0, watch.longest_s
