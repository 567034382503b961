"""The radio in fast time: the Medium of the in-process bus (bus/memory.py), SPEC §8.

The same RadioModel as the emulated network, and the same mesh shape as the real one
(ADR 0003): every drone may hold a link to the ground; a drone holds links to other
drones only as the agents' bridges (bus/mesh_policy.py, the same decisions as
agent/neighbours.py): while its direct link is not working (down, or its agent unsure
of the ground: a probe lost or retransmitted), to the neighbours its scouts hear best,
until the direct link has worked a while. A link lives while something
crosses it within the lease and is re-opened by the agents' connect retries; messages
travel the fewest-hop path over live links, each hop losing packets with the model's
loss, which a reliable transport turns into retransmission delay, and a message that
cannot cross before the link's lease runs out is lost. All of it on the virtual clock
and seeded random streams, so a run replays exactly for the same seed: one stream per
link for its upkeep, one per hop and key for what crosses it — a message added on one
key (an About, a new probe) leaves the links and every other key's fate as they were.

Figures from the real mesh (ADR 0003, docs): lease 2 s with keep-alives at a quarter
of it; connect retry every 1 s; Linux's first TCP retransmission after 200 ms,
doubling. An opened link needs its handshake (TCP SYN/SYN-ACK, Zenoh init/open) through.
"""

from __future__ import annotations

import itertools
import random
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.datagram_echo import settle_s
from dronefleet.bus.mesh_policy import ANSWER_WINDOW, HELD_WINDOW, GroundView, NeedWatch, choose, futile
from dronefleet.sim.radio import GROUND, RadioModel, Spot3, distance_3d

LEASE_S = 2.0  # a link with nothing through it for this long is closed
KEEPALIVE_S = LEASE_S / 4  # how often each link shows it is alive
RETRY_S = 1.0  # agents retry a closed link this often
HANDSHAKE_PACKETS = 4  # what must cross to open a link
RTO_S = 0.2  # first retransmission; doubles on each further loss
ROUND_S = 1.0  # agents scout their neighbours and choose bridges once a round (agent/neighbours.py)


@dataclass
class _Link:
    loss: float = 1.0
    delay_s: float = 0.0
    up: bool = False
    heard: float = 0.0  # when something last crossed
    retry_at: float = 0.0


class RadioAir:
    """Links between the nodes of a simulated field, following where they are."""

    def __init__(self, model: RadioModel, where: Callable[[], Mapping[str, Spot3]],
                 clock: VirtualClock, seed: int = 0, agent: Callable[[str], GroundView | None] | None = None) -> None:
        self.model = model
        self.agent = agent or (lambda drone: None)  # what a drone's agent makes of the ground (its probes)
        self.where = where
        self.clock = clock
        self.seed = seed
        self._streams: dict[tuple[str, ...], random.Random] = {}
        self.links: dict[tuple[str, str], _Link] = {}
        self._neighbours: dict[str, list[str]] = {}
        self._paths: dict[tuple[str, str], list[str] | None] = {}
        self._in_flight: dict[tuple[str, str], tuple[float, float]] = {}  # per directed hop: (last entry, its arrival)
        self._listeners: list[Callable[[], None]] = []
        self.bridges: dict[str, dict[str, float]] = {}  # per drone: the neighbours it holds a bridge to, and since when
        self._needs: dict[str, NeedWatch] = {}
        self._answers: dict[tuple[str, str], deque[bool]] = {}  # per drone and neighbour: its scouts answered
        self._heard_rounds: dict[tuple[str, str], int] = {}  # … and the rounds since it was first heard (agent/neighbours.py)
        self._next_round = 0.0
        # Interference a test or a bench adds on the air: (src, dst, stream) -> True loses
        # that message, whatever the links say (a shadow, a burst of loss on one stream).
        self.interference: Callable[[str, str, str], bool] | None = None
        self.tick()

    # Medium ------------------------------------------------------------------

    def reachable(self, src: str, dst: str) -> bool:
        return self.path(src, dst) is not None

    def _rng(self, *stream: str) -> random.Random:
        rng = self._streams.get(stream)
        if rng is None:
            rng = self._streams[stream] = random.Random(":".join(("radio", str(self.seed), *stream)))
        return rng

    def transit(self, src: str, dst: str, stream: str = "") -> float | None:
        path = self.path(src, dst)
        if path is None or self.interference is not None and self.interference(src, dst, stream):
            return None
        now = self.clock.monotonic()
        at = now
        for a, b in itertools.pairwise(path):
            link = self.links[_pair(a, b)]
            spent, rto, rng = link.delay_s, RTO_S, self._rng("hop", a, b, stream)
            while rng.random() < link.loss:  # lost on air: sent again after the RTO
                spent += rto
                rto *= 2
                if spent > LEASE_S:
                    return None  # the link's lease runs out first
            at = self._in_order((a, b), at, at + spent)
        return at - now

    def datagram(self, src: str, dst: str) -> float | None:
        """Seconds one datagram from src takes to reach dst over their own hop, or None:
        lost. Nothing retransmits it, and it needs no Zenoh link, only the radio: the
        ground's echo (bus/datagram_echo.py) as it fares in the air."""
        if src == dst:
            return 0.0
        link = self.links.get(_pair(self._node(src), self._node(dst)))
        if link is None:
            return None
        rng = self._rng("datagram", src, dst, "")  # the stream every seeded run drew from so far
        return None if rng.random() < link.loss else link.delay_s

    def _in_order(self, hop: tuple[str, str], enters: float, arrives: float) -> float:
        """A hop is one stream: a message arrives no earlier than one that entered it
        before (head-of-line blocking behind a retransmission). Only messages that
        entered earlier count: a forwarded message computed now may enter the hop later
        (after its first hops), and what the node itself sends before then is not
        behind it."""
        last_enters, last_arrives = self._in_flight.get(hop, (-1.0, 0.0))
        if enters >= last_enters:
            arrives = max(arrives, last_arrives)
            self._in_flight[hop] = (enters, arrives)
        return arrives

    def call_later(self, seconds: float, callback: Callable[[], None]) -> None:
        self.clock.call_later(seconds, callback)

    async def sleep(self, seconds: float) -> None:
        await self.clock.sleep(seconds)

    def on_change(self, callback: Callable[[], None]) -> None:
        self._listeners.append(callback)

    def linked(self, node: str) -> frozenset[str]:
        return frozenset(self._neighbours.get(self._node(node), ()))

    # The mesh ----------------------------------------------------------------

    def path(self, src: str, dst: str) -> list[str] | None:
        """The fewest-hop path over live links (ties: by node name), or None."""
        src, dst = self._node(src), self._node(dst)
        if (src, dst) not in self._paths:
            self._paths[(src, dst)] = self._search(src, dst)
        return self._paths[(src, dst)]

    def _search(self, src: str, dst: str) -> list[str] | None:
        came_from: dict[str, str | None] = {src: None}
        queue = deque([src])
        while queue:
            node = queue.popleft()
            if node == dst:
                path = [node]
                while (prev := came_from[path[-1]]) is not None:
                    path.append(prev)
                return path[::-1]
            for nxt in self._neighbours.get(node, []):
                if nxt not in came_from:
                    came_from[nxt] = node
                    queue.append(nxt)
        return None

    def _node(self, name: str) -> str:
        """Sessions not in the field (a test's observer) are wired to the ground."""
        return name if name in self._neighbours else GROUND

    async def run(self) -> None:
        while True:
            await self.clock.sleep(KEEPALIVE_S)
            self.tick()

    def tick(self) -> None:
        """Follow the nodes: each link's loss from their distance; links close when
        their lease runs out, or when no drone holds them as a bridge any more, and
        open again when a retry's handshake gets through."""
        where = dict(self.where())
        now = self.clock.monotonic()
        names = sorted(where)
        changed = set(names) != set(self._neighbours)
        if now >= self._next_round:
            self._next_round = now + ROUND_S
            self._round(where, now)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                link = self.links.setdefault((a, b), _Link())
                d = distance_3d(where[a], where[b])
                link.loss, link.delay_s = self.model.loss(d), self.model.delay(d) / 1000
                rng = self._rng("link", a, b)
                if not self._held(a, b):
                    if link.up:
                        link.up, changed = False, True
                    link.retry_at = now  # a bridge chosen later dials at once
                elif link.up:
                    if rng.random() >= link.loss:
                        link.heard = now
                    elif now - link.heard >= LEASE_S:
                        link.up, link.retry_at, changed = False, now + RETRY_S, True
                elif now >= link.retry_at:
                    link.retry_at = now + RETRY_S
                    if rng.random() < (1.0 - link.loss) ** HANDSHAKE_PACKETS:
                        link.up, link.heard, changed = True, now, True
        if not changed:
            return
        self._neighbours = {n: [] for n in names}
        for (a, b), link in sorted(self.links.items()):
            if link.up and a in self._neighbours and b in self._neighbours:
                self._neighbours[a].append(b)
                self._neighbours[b].append(a)
        self._paths.clear()
        for callback in self._listeners:
            callback()

    def _held(self, a: str, b: str) -> bool:
        """Every drone dials the ground; a link between two drones is a bridge one of
        them holds."""
        return GROUND in (a, b) or b in self.bridges.get(a, ()) or a in self.bridges.get(b, ())

    def _round(self, where: Mapping[str, Spot3], now: float) -> None:
        """Each drone's agent scouts once (a Scout and its Hello must both cross, no
        retransmission) and decides its bridges from the answer rates while its direct
        link is not working (agent/neighbours.py)."""
        drones = sorted(n for n in where if n != GROUND)
        for a in drones:
            heard: dict[str, deque[bool]] = {}
            rounds: dict[str, int] = {}
            for b in drones:
                if b == a:
                    continue
                answered = self._answers.setdefault((a, b), deque(maxlen=HELD_WINDOW))
                loss = self.model.loss(distance_3d(where[a], where[b]))
                answered.append(self._rng("scout", a, b).random() < (1.0 - loss) ** 2)
                heard[b] = answered
                silent = not any(list(answered)[-ANSWER_WINDOW:])  # never heard, or forgotten
                rounds[b] = self._heard_rounds[(a, b)] = 0 if silent else self._heard_rounds.get((a, b), 0) + 1
            need = self._needs.setdefault(a, NeedWatch(now))
            direct = self.links.get(_pair(a, GROUND))
            agent = self.agent(a)
            unsure = agent is not None and agent.ground_unsure()
            needed = need.update(direct is not None and direct.up and not unsure, now)
            held = self.bridges.get(a, {})
            stale = futile(held, agent.ground_heard_at(), now) if agent is not None else set()
            chosen = choose(heard, set(held), stale, rounds) if needed else set()
            self.bridges[a] = {b: held.get(b, now) for b in sorted(chosen)}


class AirEcho:
    """The ground's datagram echo as a drone's agent sees it in fast time (the EchoPort
    of bus/datagram_echo.py): each datagram and its echo cross the drone's own hop to
    the ground with the radio model's loss, never retransmitted. A train is drawn at
    once, halfway through its spread (the drone moves a few metres meanwhile; one draw
    per datagram would cost the corpus a timer each), and answered on the virtual clock
    when the last datagram would have come back."""

    def __init__(self, air: RadioAir, node: str) -> None:
        self.air = air
        self.node = node

    async def train(self, count: int, spacing_s: float, timeout_s: float) -> list[float | None]:
        spread_s = (count - 1) * spacing_s
        await self.air.sleep(spread_s / 2)  # drawn where the drone is halfway through the train
        rtts: list[float | None] = []
        for _ in range(count):
            out = self.air.datagram(self.node, GROUND)
            back = None if out is None else self.air.datagram(GROUND, self.node)
            rtts.append(None if out is None or back is None else (out + back) * 1000.0)
        answered = [r / 1000.0 for r in rtts if r is not None]
        await self.air.sleep(spread_s / 2 + (max(answered) if len(answered) == count else settle_s(answered, timeout_s)))
        return rtts

    def close(self) -> None:
        pass


def _pair(a: str, b: str) -> tuple[str, str]:
    return (a, b) if a < b else (b, a)
