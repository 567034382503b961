"""A drone shown is a drone that answers (issue 57): a command to a drone the ground
hears but whose command queryable has not reached the ground yet (one that registered
a moment ago through a neighbour) is asked again until it answers, within the
command's deadline; past the deadline the error says why. In fast time (SimField: the
real ground station on the in-process bus)."""

from __future__ import annotations

import asyncio
import json

import msgspec
import pytest

from dronefleet.bus.port import NoRoute
from dronefleet.compose import SimField
from dronefleet.schemas.codec import encode
from dronefleet.schemas.commands import CommandReply
from tests.ground.test_ground_input import field  # noqa: F401 (the fast-time field: the real station, two drones)


def _heard_as(sim: SimField, drone_id: str) -> None:
    """A node the ground hears as `drone_id` (drone01's telemetry under its name)."""
    telem = msgspec.structs.replace(sim.station.registry.telemetry("drone01"), drone_id=drone_id)
    sim._bus(drone_id).publish(f"drone/{drone_id}/telem", encode(telem))


async def _answer(selector: str, payload: bytes) -> bytes:
    return encode(CommandReply(command_id=json.loads(payload)["command_id"], accepted=True))


@pytest.mark.parametrize("late_s", [0.0, 0.3, 2.0])
async def test_a_heard_drone_whose_queryable_comes_late_takes_the_command(field: SimField, late_s: float) -> None:  # noqa: F811
    await field.clock.advance(1.0)
    _heard_as(field, "drone09")
    await field.clock.advance(0.1)
    assert "drone09" in field.station.registry
    asked: list[bytes] = []

    async def answer(selector: str, payload: bytes) -> bytes:
        asked.append(payload)
        return await _answer(selector, payload)

    sending = asyncio.ensure_future(field.station.command("drone09", b'{"cmd": "arm", "command_id": "c1"}'))
    await field.clock.advance(late_s)
    served = field._bus("drone09").serve("drone/drone09/cmd", answer)
    try:
        await field.clock.advance(1.0)
        assert sending.done() and sending.result().accepted
        assert len(asked) == 1  # asked again only while nobody was there to hear it
    finally:
        served.close()


async def test_past_the_deadline_a_heard_drone_with_no_route_is_named(field: SimField) -> None:  # noqa: F811
    await field.clock.advance(1.0)
    _heard_as(field, "drone09")
    await field.clock.advance(0.1)
    sending = asyncio.ensure_future(field.station.command("drone09", b'{"cmd": "arm"}'))
    start = field.clock.monotonic()
    while not sending.done():
        await field.clock.advance(0.1)
    waited = field.clock.monotonic() - start
    deadline_s = field.station.config.command_timeout_ms / 1000
    assert deadline_s - 0.6 <= waited <= deadline_s + 0.2, waited
    with pytest.raises(NoRoute, match=r"no route to drone/drone09/cmd within 3 s"):
        sending.result()
