"""The ground against garbage from the mesh (issue 31): malformed payloads, a status
naming another drone, a very large payload, one key flooding. Each is ignored with a
log line; nothing crashes and no drone's state changes. In fast time (SimField: the
real ground station on the in-process bus)."""

from __future__ import annotations

import json
import logging

import pytest

from dronefleet.compose import SimField
from dronefleet.ground.throttle import BURST, WINDOW_MS
from dronefleet.sim.world import World

GARBAGE = [b"", b"\x00\xff\xfe", b"not json", b"[1, 2, 3]", b'{"drone_id": "drone01"}',
           b'{"drone_id": "drone01", "timestamp": "soon"}', b"{" * 10_000]


@pytest.fixture
async def field() -> SimField:  # type: ignore[misc]
    sim = SimField(World(), 2)
    await sim.start()
    try:
        yield sim
    finally:
        await sim.close()


async def test_malformed_messages_are_logged_and_change_nothing(field: SimField, caplog: pytest.LogCaptureFixture) -> None:
    station = field.station
    await field.clock.advance(1.0)
    before = station.registry.telemetry("drone01")
    rogue = field._bus("drone02")
    caplog.set_level(logging.WARNING, logger="dronefleet.ground.station")
    for kind in ("telem", "status", "sensor/temperature", "link"):
        for payload in GARBAGE:
            rogue.publish(f"drone/drone01/{kind}", payload)
    rogue.publish("drone/drone01/telem", b"x" * (8 << 20))  # 8 MiB of junk
    for _ in range(2000):  # one key flooding
        rogue.publish("drone/drone01/link", b"\x00")
    await field.clock.advance(0.05)
    warnings = [r.getMessage() for r in caplog.records]
    assert sum("ignored a bad message on drone/drone01/" in w for w in warnings) >= 4 * len(GARBAGE)
    # The flooding key fills the log with no more than a burst; the rest are counted,
    # and the key's next warning after the window says how many were held back.
    flood = [w for w in warnings if "on drone/drone01/link" in w]
    assert len(flood) == BURST and "further warnings on this key are counted" in flood[-1], flood[-3:]
    await field.clock.advance(WINDOW_MS / 1000)
    rogue.publish("drone/drone01/link", b"\x00")
    await field.clock.advance(0.05)
    held = len(GARBAGE) + 2000 - BURST
    assert f"({held} more on this key held back before this one)" in caplog.records[-1].getMessage()
    after = station.registry.telemetry("drone01")
    assert after.seq >= before.seq and after.drone_id == "drone01"
    # Still serving: drone01 takes a command.
    reply = await station.command("drone01", b'{"cmd": "arm"}')
    assert reply.accepted


async def test_a_status_naming_another_drone_is_ignored(field: SimField, caplog: pytest.LogCaptureFixture) -> None:
    station = field.station
    await field.clock.advance(1.0)
    caplog.set_level(logging.WARNING, logger="dronefleet.ground.station")
    spoof = {"drone_id": "drone01", "timestamp": field.clock.time_ms(), "component": "system", "state": "failsafe",
             "reason": "spoofed"}
    field._bus("drone02").publish("drone/drone02/status", json.dumps(spoof).encode())
    await field.clock.advance(0.05)
    assert any("names drone 'drone01'" in r.getMessage() for r in caplog.records)
    logged = [line.message for _, line in station.events.query(drone_ids=["drone01"])]
    assert logged and not any("spoofed" in message or "ailsafe" in message for message in logged), logged
