"""A standby's copy of the active ground's event log (SPEC §14, bus/stream_copy.py) on
an in-memory mesh: lines lost on their way are asked for when the next one shows the
gap, a ground that joined late catches up from the active ground's announcement, and
nothing is kept twice."""

from __future__ import annotations

import asyncio
from pathlib import Path

import msgspec

from dronefleet.bus.faulty import FaultyBus
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.bus.stream_copy import StreamCopy
from dronefleet.ground.eventlog import EventLog
from dronefleet.ground.registry import LogLine
from dronefleet.schemas.keys import Keys
from tests.waiting import until


def line(n: int) -> LogLine:
    return LogLine(timestamp=1_000 + n, level="info", drone_id="drone01", message=f"line {n}")


async def test_lost_lines_are_caught_up_and_a_late_copy_catches_up_from_the_announcement(tmp_path: Path) -> None:
    network = MemoryNetwork()
    lost = {3, 4, 7}
    active_bus = FaultyBus(MemoryBus(network, "alpha"),
                           lose=lambda key, payload: key.endswith("/log") and any(f'"seq":{n},' in payload.decode() for n in lost))
    active_log, copy_log = EventLog(tmp_path / "a.db"), EventLog(tmp_path / "b.db")
    active = StreamCopy(active_bus, Keys(), "alpha", active_log.stream())
    standby = StreamCopy(MemoryBus(network, "bravo"), Keys(), "bravo", copy_log.stream())
    declared = [*active.declare(), *standby.declare()]
    try:
        for n in range(1, 9):
            seq = active_log.append(line(n))
            active.published(seq, msgspec.structs.asdict(line(n)))
            await asyncio.sleep(0)  # the loop delivers in order, as the mesh does per key

        async def all_kept() -> bool:
            return [s for s, _ in copy_log.copies("alpha")] == list(range(1, 9))
        await until(all_kept, 5, "every line in the copy")
        assert [x.message for _, x in copy_log.copies("alpha")] == [f"line {n}" for n in range(1, 9)]
        assert len(active_bus.lost) == 3  # the copy asked for them, not a second publication

        late_log = EventLog(tmp_path / "c.db")
        late = StreamCopy(MemoryBus(network, "charlie"), Keys(), "charlie", late_log.stream())
        declared += late.declare()
        late.heard_active("alpha", active_log.last_id())  # what the active ground's announcement carries

        async def caught_up() -> bool:
            return late.upto("alpha") == 8
        await until(caught_up, 5, "the late copy caught up")
        late.heard_active("alpha", 8)
        assert late_log.copies("alpha", after_seq=8) == [] and late.upto("alpha") == 8
    finally:
        for d in declared:
            d.close()
