"""The agent's link probe (SPEC §8): every period, one query to `ground/ping` and one
to each neighbour's `drone/<id>/ping`, over whatever path the mesh takes; each
outcome feeds that peer's window, and a LinkQuality per peer goes out on
`drone/<id>/link`. Neighbours are the drones whose liveliness token this agent sees.

To the ground, each probe also sends a train of datagrams to the ground's echo
(`echo`, bus/datagram_echo.py): while the drone's traffic takes its own hop and the
ground has echoed once, the report's loss, RTT and jitter come from those datagrams,
which nothing retransmits, so quality falls as the hop starts to lose packets and
not only once it is gone (agent/link.py, ADR 0003).

An answered ground probe is the agent's sign of the ground: `on_ground_contact` is
called with its time, which drives the lost-link policy. Each report says whether the
answers of its window came over the drone's own link to the peer (`hops` 1) or some
through other drones (2): a relay plugin proves a hop only by the first (relay/chain.py).
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable

import msgspec

from dronefleet.agent.link import DELIVERY_TRAINS, TRAIN, TRAIN_SPREAD, WINDOW, DeliveryWindow, LinkSummary, LinkWindow
from dronefleet.bus.clock import Clock
from dronefleet.bus.datagram_echo import EchoPort
from dronefleet.bus.mesh_policy import RETRANSMITTED_MS
from dronefleet.bus.port import Bus, BusError
from dronefleet.schemas.codec import encode
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.probe import Ping, ping_decoder
from dronefleet.schemas.telemetry import GROUND_PEER, LinkQuality

log = logging.getLogger(__name__)


class LinkProber:
    def __init__(
        self, drone_id: str, bus: Bus, keys: Keys, clock: Clock, period_s: float,
        on_ground_contact: Callable[[float], None], window: int = WINDOW, echo: EchoPort | None = None,
        on_unrouted: Callable[[], None] = lambda: None,
    ) -> None:
        self.drone_id = drone_id
        self.bus = bus
        self.keys = keys
        self.clock = clock
        self.period_s = period_s
        self.on_ground_contact = on_ground_contact
        self.on_unrouted = on_unrouted  # the ground hears this drone but cannot reach its commands
        self.window = window
        self.windows: dict[str, LinkWindow] = {GROUND_PEER: LinkWindow(window)}
        self.echo = echo
        self.delivery = DeliveryWindow(DELIVERY_TRAINS)
        # per peer and probe of the window: answered, and over one link (None: unknown)
        self.linked: dict[str, deque[tuple[bool, bool | None]]] = {}
        self.neighbours: set[str] = set()
        self._seq = 0
        self._ground_sent: float | None = None  # when the probe to the ground now out went
        self._ground_path: tuple[bool | None, int | None] = (None, None)  # last ground probe: over one link, hops

    def ground_overdue(self, now: float) -> bool:
        """The probe to the ground now out has waited longer than a clean round trip
        takes (`bus.mesh_policy.RETRANSMITTED_MS`): it is lost or retransmitted, whatever
        its outcome. Waiting for that had a worker's link counted clean while its loss
        climbed to 80 % (fast-time corpus)."""
        return self._ground_sent is not None and (now - self._ground_sent) * 1000 > RETRANSMITTED_MS

    def on_liveliness(self, key: str, alive: bool) -> None:
        parsed = self.keys.parse(key)
        if parsed is None or parsed.drone_id == self.drone_id:
            return
        if alive:
            self.neighbours.add(parsed.drone_id)
            self.windows.setdefault(parsed.drone_id, LinkWindow(self.window))
        else:
            self.neighbours.discard(parsed.drone_id)

    async def run(self) -> None:
        watch = self.bus.watch_liveliness(self.keys.alive(), self.on_liveliness)
        try:
            next_at = self.clock.monotonic()
            while True:
                await self.probe_all()
                next_at += self.period_s
                await self.clock.sleep(max(0.0, next_at - self.clock.monotonic()))
        finally:
            watch.close()

    async def probe_all(self) -> None:
        peers = [GROUND_PEER, *sorted(self.neighbours)]
        ground = asyncio.ensure_future(self._report_ground()) if self.echo is not None else None
        try:
            outcomes = await asyncio.gather(*(self._probe(peer) for peer in peers))
        except BaseException:
            if ground is not None:
                ground.cancel()
            raise
        for peer, (rtt, direct) in zip(peers, outcomes, strict=True):
            window = self.windows[peer]
            window.add(rtt)
            linked = self.linked.setdefault(peer, deque(maxlen=self.window))
            linked.append((rtt is not None, direct))
            answers = [d for answered, d in linked if answered]
            hops = None if not answers or None in answers else (1 if all(answers) else 2)
            if peer == GROUND_PEER:
                self._ground_path = (direct, hops)
            if peer != GROUND_PEER or ground is None:
                self._report(peer, window.summary(), hops)
        if ground is not None:
            await ground

    async def _report_ground(self) -> None:
        """The ground's report, as soon as its train is back: a Zenoh probe that a lossy
        hop retransmits does not hold it back, since the report then says least late
        what the hop does. Its path is the last probe answered (this one's, when it
        came back first, as it does on a clean hop)."""
        self.delivery.add(await self._train())
        direct, hops = self._ground_path
        window = self.windows[GROUND_PEER]
        if not self.delivery.echoed and not window.outcomes():
            return  # nothing known yet: the first probe is still out and no echo came back
        self._report(GROUND_PEER, self._ground_summary(window, direct), hops)

    def _report(self, peer: str, s: LinkSummary, hops: int | None) -> None:
        quality = LinkQuality(
            drone_id=self.drone_id, timestamp=self.clock.time_ms(), peer=peer,
            rtt_ms=s.rtt_ms, jitter_ms=s.jitter_ms, loss=s.loss, quality=s.quality, hops=hops,
        )
        try:
            self.bus.publish(self.keys.link(self.drone_id), encode(quality), reliable=False)
        except BusError as exc:
            log.debug("%s: link quality not published: %s", self.drone_id, exc)

    async def _train(self) -> list[float | None]:
        """One train to the ground's echo, spread over TRAIN_SPREAD of a period and
        answered within a few round trips (at most 30 % of a period more): what the
        report says is a few tenths of a second old (ADR 0003)."""
        assert self.echo is not None
        spacing_s = self.period_s * TRAIN_SPREAD / TRAIN
        try:
            return await self.echo.train(TRAIN, spacing_s, timeout_s=self.period_s * 0.3)
        except OSError as exc:  # no route at all: every datagram lost
            log.debug("%s: echo train not sent: %s", self.drone_id, exc)
            return [None] * TRAIN

    def _ground_summary(self, window: LinkWindow, direct: bool | None) -> LinkSummary:
        """The ground's report: from the datagrams while they measure the path (the
        ground echoes, and the last answer did not come through another drone), else
        from the probes."""
        if not self.delivery.echoed or direct is False:
            return window.summary()
        # The datagrams alone: a Zenoh probe answered late because the laptop or the
        # drone was busy is not radio loss (counted as loss, one slow probe under the
        # suite's load read as quality 0 at 20 m). A ground that stops answering
        # altogether is the lost-link policy's, on its own clock.
        return self.delivery.summary()

    async def _probe(self, peer: str) -> tuple[float | None, bool | None]:
        """The round trip in ms (None: unanswered), and whether the answer came over one link."""
        self._seq += 1
        key = self.keys.ground_ping() if peer == GROUND_PEER else self.keys.ping(peer)
        ping = Ping(drone_id=self.drone_id, timestamp=self.clock.time_ms(), seq=self._seq)
        sent = self.clock.monotonic()
        if peer == GROUND_PEER:
            self._ground_sent = sent
        try:
            answer, direct = await self.bus.query_linked(key, encode(ping), timeout_s=self.period_s)
        except (BusError, TimeoutError):
            return None, None
        finally:
            if peer == GROUND_PEER:
                self._ground_sent = None
        now = self.clock.monotonic()
        if peer == GROUND_PEER:
            self.on_ground_contact(now)
            if _asks_redeclare(answer):
                self.on_unrouted()
        return (now - sent) * 1000.0, direct


def _asks_redeclare(answer: bytes) -> bool:
    try:
        return ping_decoder.decode(answer).redeclare
    except msgspec.MsgspecError:  # a plain echo from some other ground: nothing asked
        return False
