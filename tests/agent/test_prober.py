"""The agent's link prober (agent/prober.py) on the in-process bus and virtual clock."""

from __future__ import annotations

import asyncio

from dronefleet.agent.prober import LinkProber
from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.bus.mesh_policy import RETRANSMITTED_MS
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import GROUND_PEER


def slow_ground(keys: Keys) -> tuple[MemoryBus, MemoryBus, asyncio.Event]:
    """A ground whose ping answers only once the event is set, and a drone's bus."""
    network = MemoryNetwork()
    ground, drone = MemoryBus(network, "ground"), MemoryBus(network, "drone01")
    answer = asyncio.Event()

    async def slow_echo(key: str, payload: bytes) -> bytes:
        await answer.wait()
        return payload

    ground.serve(keys.ground_ping(), slow_echo)
    return ground, drone, answer


async def test_a_ground_probe_out_longer_than_a_clean_round_trip_is_overdue_before_its_outcome() -> None:
    """A worker's link counted clean while its loss climbed
    to 80 %, its probes neither answered nor timed out yet. A probe out longer than a
    clean round trip takes counts at once (the drone bridges: ADR 0003)."""
    clock, keys = VirtualClock(), Keys()
    ground, drone, answer = slow_ground(keys)
    contacts: list[float] = []
    prober = LinkProber("drone01", drone, keys, clock, 1.0, on_ground_contact=contacts.append)
    probe = asyncio.ensure_future(prober.probe_all())
    await asyncio.sleep(0)
    assert not prober.ground_overdue(clock.monotonic())  # just sent
    await clock.advance(RETRANSMITTED_MS / 1000 / 2)
    assert not prober.ground_overdue(clock.monotonic())
    await clock.advance(RETRANSMITTED_MS / 1000)
    assert prober.ground_overdue(clock.monotonic())  # still out: retransmitted or lost
    answer.set()
    await probe
    assert contacts and not prober.ground_overdue(clock.monotonic())
    assert prober.windows[GROUND_PEER].outcomes()[-1] is not None


class QuickEcho:
    """A ground echo whose datagrams all come back 10 ms after they went (EchoPort)."""

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock

    async def train(self, count: int, spacing_s: float, timeout_s: float) -> list[float | None]:
        await self.clock.sleep(count * spacing_s + 0.01)
        return [10.0] * count

    def close(self) -> None:
        pass


async def test_the_ground_report_goes_out_when_its_train_is_back_not_after_a_retransmitted_probe() -> None:
    """On a lossy hop the probe's Zenoh query is retransmitted and answers late; the
    report the ground reads is the datagrams', so it goes out when they are back
    (ADR 0003): held for the query, it was up to a period older."""
    clock, keys = VirtualClock(), Keys()
    ground, drone, answer = slow_ground(keys)
    reports: list[float] = []
    ground.subscribe(keys.link("drone01"), lambda s: reports.append(clock.monotonic()))
    prober = LinkProber("drone01", drone, keys, clock, 1.0, on_ground_contact=lambda _: None, echo=QuickEcho(clock))
    probe = asyncio.ensure_future(prober.probe_all())
    await clock.advance(0.5)
    assert len(reports) == 1 and reports[0] <= 0.4, reports  # the train's 0.3 s and its echoes
    assert not probe.done()  # the query is still out
    answer.set()
    await probe
    assert len(reports) == 1  # one report per period all the same
