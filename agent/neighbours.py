"""Links to neighbouring drones only while this drone needs them (ADR 0003).

A router forwards what it receives to every neighbour it is linked to, and a push
towards a lossy or stalled neighbour holds the router (Zenoh 1.10, #1876): a drone
20 m from the laptop went deaf for seconds because its router was linked to drones
85 m away. So an agent's router never dials a neighbour by itself (no gossip or
multicast autoconnect on the radio), and this task decides:

- every round (1 s) it multicasts one Zenoh Scout on the mesh interface and counts
  which neighbours' routers answer: the answer rate over the last rounds measures
  the hop (a Scout and its Hello both had to cross) without holding a link;
- while the drone has no working direct link to the ground (its own router has no
  link to a `connect` endpoint, or one of the ground's last probes went unanswered or
  was retransmitted: `bus.mesh_policy.unsure`), it holds a
  *bridge* to the best neighbours: a small router session in this process linked to
  its own router (loopback) and to the neighbour's, so link-state routing carries the
  drone's traffic through that neighbour. Neighbours answering well are preferred,
  and none answering under `bus.mesh_policy.KEEP_RATE` is ever used;
- once the direct link has worked for `DIRECT_STEADY_S`, the bridges close.

A bridge is closed by closing its session, which the Zenoh API allows (a transport of
the main session cannot be closed, nor an endpoint added to it after open).
"""

from __future__ import annotations

import asyncio
import collections
import fcntl
import ipaddress
import logging
import secrets
import socket
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from dronefleet.bus.mesh_policy import (
    ANSWER_WINDOW,
    DIRECT_STEADY_S,
    HELD_WINDOW,
    MAX_BRIDGES,
    GroundView,
    NeedWatch,
    choose,
    futile,
    rate,
)
from dronefleet.bus.sockets import shutdown_tcp_to
from dronefleet.bus.zenoh_bus import ZenohBus, zenoh_config
from dronefleet.schemas.endpoints import ip_endpoint, plain_endpoint

log = logging.getLogger(__name__)

ROUND_S = 1.0  # one Scout per round
HELLOS_PER_ROUND = 256  # answers kept from one round (one per router in range)
# A bridge opens only if both its links are up within this, or not at all. With
# Zenoh's retry-for-ever connect (the agent's own), a bridge the agent had already
# given up on linked into a neighbour 8 s later over a lossy hop, while it was
# being closed, and that neighbour's ground link expired (bench/mesh_stall.py, ADR 0003).
BRIDGE_CONNECT_MS = 2000
SIOCGIFADDR, SIOCGIFNETMASK = 0x8915, 0x891B


def interface_network(interface: str) -> ipaddress.IPv4Interface:
    """The IPv4 address and network of an interface (OSError if it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        name = struct.pack("256s", interface.encode()[:15])
        address = socket.inet_ntoa(fcntl.ioctl(s.fileno(), SIOCGIFADDR, name)[20:24])
        mask = socket.inet_ntoa(fcntl.ioctl(s.fileno(), SIOCGIFNETMASK, name)[20:24])
    return ipaddress.IPv4Interface(f"{address}/{mask}")


def radio_locator(locators: Sequence[str], network: ipaddress.IPv4Network) -> str | None:
    """The neighbour's locator on the radio's network (a Hello lists every address
    its router listens on: loopback, the radio, other interfaces)."""
    for locator in locators:
        parsed = ip_endpoint(locator)
        try:
            if parsed is not None and ipaddress.IPv4Address(parsed[1]) in network:
                return plain_endpoint(locator)
        except ValueError:  # an IPv6 or named host
            continue
    return None


@dataclass
class Heard:
    """One neighbour's router as the scouting rounds heard it."""

    locator: str
    answers: collections.deque[bool] = field(default_factory=lambda: collections.deque(maxlen=HELD_WINDOW))
    rounds: int = 0  # rounds since it was first heard (it is forgotten after ANSWER_WINDOW unheard)

    @property
    def rate(self) -> float:
        return rate(self.answers)


class Neighbours:
    """The scouting rounds and the bridges of one agent; `run()` until cancelled."""

    def __init__(
        self, drone_id: str, bus: ZenohBus, interface: str, ground_endpoints: Sequence[str],
        own_endpoint: str, ground: GroundView, *, extra: dict[str, Any] | None = None,
        zids: frozenset[str] = frozenset(),
    ) -> None:
        self.drone_id = drone_id
        self.bus = bus
        self.interface = interface
        self.ground_endpoints = {plain_endpoint(e) for e in ground_endpoints}
        self.own_endpoint = own_endpoint
        self.ground = ground
        self.extra = extra or {}
        self.free_zids = sorted(zids)  # the bridges' own ZIDs, which this drone's router trusts (secured mesh)
        self._zid_of: dict[str, str] = {}
        self.heard: dict[str, Heard] = {}
        self.bridges: dict[str, zenoh.Session] = {}
        self._opened: dict[str, float] = {}  # per bridge: when it opened (loop time)

    def direct_link(self) -> bool:
        """The agent's router holds a link it dialled to one of the ground's endpoints."""
        return any(plain_endpoint(str(link.dst)) in self.ground_endpoints for link in self.bus.session.info.links())

    async def run(self) -> None:
        network = interface_network(self.interface).network
        own = {str(self.bus.session.info.zid())}
        loop = asyncio.get_running_loop()
        need = NeedWatch(loop.time())
        try:
            while True:
                hellos = await self._scout_round()
                answered: dict[str, str] = {}
                for zid, locators in hellos:
                    if zid in own or zid in answered:
                        continue
                    locator = radio_locator(locators, network)
                    if locator is not None:
                        answered[zid] = locator
                for zid, locator in answered.items():
                    self.heard.setdefault(zid, Heard(locator)).locator = locator
                for zid, heard in list(self.heard.items()):
                    heard.answers.append(zid in answered)
                    heard.rounds += 1
                    if len(heard.answers) >= ANSWER_WINDOW and heard.rate == 0.0 and zid not in self.bridges:
                        del self.heard[zid]  # gone (a restarted agent comes back under a new ZID)
                was_needed = need.needed
                direct = await asyncio.to_thread(self.direct_link)  # a Zenoh call: off the loop, as stop() above
                needed = need.update(direct and not self.ground.ground_unsure(), loop.time())
                if needed != was_needed:
                    log.info("%s: %s", self.drone_id, "no working direct link to the ground; relaying through neighbours"
                             if needed else f"the direct link to the ground has worked {DIRECT_STEADY_S:g} s; "
                             "closing the links through neighbours")
                stale = futile(self._opened, self.ground.ground_heard_at(), loop.time())
                wanted = choose({z: h.answers for z, h in self.heard.items()}, set(self.bridges), stale,
                                {z: h.rounds for z, h in self.heard.items()}) if needed else set()
                for zid in set(self.bridges) - wanted:
                    await self._close(zid)
                for zid in wanted - set(self.bridges):
                    await self._open(zid)
        finally:
            for zid in list(self.bridges):
                await self._close(zid)

    async def _scout_round(self) -> list[tuple[str, list[str]]]:
        """One Scout for routers on the radio; the Hellos heard within the round."""
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "true")
        conf.insert_json5("scouting/multicast/interface", f'"{self.interface}"')
        scout = await asyncio.to_thread(
            lambda: zenoh.scout(zenoh.handlers.FifoChannel(HELLOS_PER_ROUND), what="router", config=conf))
        hellos = []
        try:
            await asyncio.sleep(ROUND_S * 0.8)
            while (hello := scout.try_recv()) is not None:
                hellos.append((str(hello.zid), [str(loc) for loc in hello.locators]))
        finally:
            # Never on the event loop: Zenoh's Scout.stop() waits (up to 10 s) for the
            # scout task to end, and that task runs on the runtime that also accepts
            # links; while a neighbour's link was being accepted over a lossy hop, a
            # stop held this agent's loop 9.9 s and its telemetry with it (ADR 0003).
            await asyncio.to_thread(scout.stop)
        await asyncio.sleep(ROUND_S * 0.2)
        return hellos

    async def _open(self, zid: str) -> None:
        heard = self.heard[zid]
        extra = {
            **self.extra, "listen/endpoints": [],
            "scouting/gossip/autoconnect": {"router": [], "peer": []},
            "connect/timeout_ms": BRIDGE_CONNECT_MS, "connect/exit_on_failure": True,
        }
        own_zid = self.free_zids.pop() if self.free_zids else None
        if own_zid is not None:
            extra["id"] = own_zid
        conf = zenoh_config("router", [heard.locator, self.own_endpoint], extra=extra)
        try:
            self.bridges[zid] = await asyncio.to_thread(zenoh.open, conf)
        except zenoh.ZError as exc:
            if own_zid is not None:
                self.free_zids.append(own_zid)
            log.warning("%s: no link through neighbour %s (%s): %s", self.drone_id, zid, heard.locator, exc)
            return
        if own_zid is not None:
            self._zid_of[zid] = own_zid
        self._opened[zid] = asyncio.get_running_loop().time()
        log.info("%s: linking through neighbour %s at %s (answers %.0f %% of scouts)",
                 self.drone_id, zid, heard.locator, 100 * heard.rate)

    async def _close(self, zid: str) -> None:
        session = self.bridges.pop(zid)
        self._opened.pop(zid, None)
        if zid in self._zid_of:
            self.free_zids.append(self._zid_of.pop(zid))
        log.info("%s: link through neighbour %s closed", self.drone_id, zid)
        heard = self.heard.get(zid)
        where = ip_endpoint(heard.locator) if heard is not None else None
        if where is not None and where[0] in ("tcp", "tls"):
            # Its link first, at once: the session's own close takes ~10 s over a lossy
            # hop and leaves the link open, unread, holding the neighbour (bus/sockets.py).
            await asyncio.to_thread(shutdown_tcp_to, where[1], where[2])
        try:
            await asyncio.to_thread(session.close)
        except zenoh.ZError:
            pass


def new_bridge_zids() -> frozenset[str]:
    """ZIDs for this agent's bridges, chosen at start so its router's access rules can
    name them (bus/mesh_security.py): 32 hex digits, the first not 0 (Zenoh drops
    leading zeros when it prints one)."""
    zids: set[str] = set()
    while len(zids) < MAX_BRIDGES:
        zid = secrets.token_hex(16)
        if zid[0] != "0":
            zids.add(zid)
    return frozenset(zids)
