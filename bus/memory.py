"""In-process Bus with Zenoh's semantics, for unit tests and fast-time simulation.

A MemoryNetwork plays the router; each MemoryBus is one session on it. Samples
travel through the same bounded Inbox as on Zenoh, a get with no matching
queryable ends at once, a slow queryable times out, and closing a session drops
its liveliness tokens as a dead node's would.

Each session sits on a node of the mesh (the ground, a drone; on-board programs
share their drone's node). Without a Medium every node reaches every other at
once. With one (fast time: sim/radio_air.py) a message between two nodes crosses
it hop by hop and may arrive late or never, a query times out on the Medium's
clock, and a liveliness token is seen only where its node can be reached, as on
the real mesh.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from dronefleet.bus.inbox import Inbox
from dronefleet.bus.keyexpr import intersects, strip_parameters
from dronefleet.bus.port import (
    LivelinessHandler,
    NoRoute,
    QueryHandler,
    QueryRefused,
    QueryTimeout,
    RouteHandler,
    Sample,
    SampleHandler,
)


class Medium(Protocol):
    """What lies between the nodes: reachability, transit time, and the clock it runs on."""

    def reachable(self, src: str, dst: str) -> bool: ...

    def transit(self, src: str, dst: str, stream: str = "") -> float | None:
        """Seconds one message from src takes to reach dst now; None: it never arrives.
        `stream` (the message's key) may give each key its own random draws."""
        ...

    def call_later(self, seconds: float, callback: Callable[[], None]) -> None: ...

    async def sleep(self, seconds: float) -> None: ...

    def path(self, src: str, dst: str) -> list[str] | None:
        """The nodes a message from `src` to `dst` passes (both ends), or None."""

    def on_change(self, callback: Callable[[], None]) -> None:
        """Call back whenever which nodes reach which may have changed."""
        ...

    def linked(self, node: str) -> frozenset[str]:
        """The nodes `node` holds a live link to."""
        ...


@dataclass(eq=False)
class _Decl:
    keyexpr: str
    owner: MemoryBus
    on_close: Callable[[], None]
    closed: bool = False

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.on_close()


@dataclass
class MemoryNetwork:
    """Every declaration of every session, by kind, and the Medium between their nodes."""

    medium: Medium | None = None
    subscribers: list[tuple[_Decl, Inbox[Sample]]] = field(default_factory=list)
    queryables: list[tuple[_Decl, QueryHandler]] = field(default_factory=list)
    tokens: list[_Decl] = field(default_factory=list)
    watchers: list[tuple[_Decl, Inbox[tuple[str, bool]]]] = field(default_factory=list)
    routes: list[Callable[[], None]] = field(default_factory=list)  # each route watch's check
    answering: set[asyncio.Task[Any]] = field(default_factory=set)  # queryables running for a remote asker
    # The tokens each watcher has been told are alive (what it sees of the mesh).
    _seen: dict[_Decl, set[_Decl]] = field(default_factory=dict)
    # Per key, the subscriptions and queryables it matches, in declaration order: a
    # field of a dozen drones publishes a hundred thousand samples a mission, each of
    # which scanned every subscription. Dropped whenever a declaration comes or goes.
    _subscribed: dict[str, list[tuple[_Decl, Inbox[Sample]]]] = field(default_factory=dict)
    _served: dict[str, list[tuple[_Decl, QueryHandler]]] = field(default_factory=dict)

    def add_subscriber(self, entry: tuple[_Decl, Inbox[Sample]]) -> None:
        self.subscribers.append(entry)
        self._subscribed.clear()

    def remove_subscriber(self, entry: tuple[_Decl, Inbox[Sample]]) -> None:
        self.subscribers.remove(entry)
        self._subscribed.clear()

    def add_queryable(self, entry: tuple[_Decl, QueryHandler]) -> None:
        self.queryables.append(entry)
        self._served.clear()

    def remove_queryable(self, entry: tuple[_Decl, QueryHandler]) -> None:
        self.queryables.remove(entry)
        self._served.clear()

    def subscribed(self, key: str) -> list[tuple[_Decl, Inbox[Sample]]]:
        """The subscriptions whose key expressions match `key`."""
        found = self._subscribed.get(key)
        if found is None:
            found = self._subscribed[key] = [entry for entry in self.subscribers if intersects(entry[0].keyexpr, key)]
        return found

    def served(self, key: str) -> list[tuple[_Decl, QueryHandler]]:
        """The queryables whose key expressions match `key`."""
        found = self._served.get(key)
        if found is None:
            found = self._served[key] = [entry for entry in self.queryables if intersects(entry[0].keyexpr, key)]
        return found

    def __post_init__(self) -> None:
        if self.medium is not None:
            self.medium.on_change(self._reconsider_tokens)
            self.medium.on_change(self.reconsider_routes)

    def routed(self, node: str, key: str) -> bool:
        """Whether a query on `key` from `node` finds a queryable (as `query` looks)."""
        return any(self.reachable(node, d.owner.node) for d, _ in self.served(key))

    def reconsider_routes(self) -> None:
        for check in list(self.routes):
            check()

    def reachable(self, src: str, dst: str) -> bool:
        return self.medium is None or src == dst or self.medium.reachable(src, dst)

    def carry(self, src: str, dst: str, deliver: Callable[[], None], stream: str = "") -> None:
        """One message (on key `stream`) from node src to node dst: now, later, or (lost) never."""
        if self.medium is None or src == dst:
            deliver()
            return
        delay = self.medium.transit(src, dst, stream)
        if delay is not None:
            self.medium.call_later(delay, deliver)

    def _tell(self, watcher: tuple[_Decl, Inbox[tuple[str, bool]]], token: _Decl, alive: bool) -> None:
        seen = self._seen.setdefault(watcher[0], set())
        if alive == (token in seen):
            return
        (seen.add if alive else seen.discard)(token)
        watcher[1].put_nowait((token.keyexpr, alive))

    def _tell_watchers(self, token: _Decl, alive: bool) -> None:
        for watcher in self.watchers:
            decl = watcher[0]
            if intersects(decl.keyexpr, token.keyexpr) and (not alive or self.reachable(token.owner.node, decl.owner.node)):
                self._tell(watcher, token, alive)

    def _reconsider_tokens(self) -> None:
        """The mesh changed shape: tokens come into and go out of each watcher's sight."""
        for watcher in list(self.watchers):
            decl = watcher[0]
            for token in self.tokens:
                if intersects(decl.keyexpr, token.keyexpr):
                    self._tell(watcher, token, self.reachable(token.owner.node, decl.owner.node))


class MemoryBus:
    _ids = itertools.count(1)

    def __init__(self, network: MemoryNetwork, node: str = "") -> None:
        self._net = network
        self.node = node  # where on the mesh this session runs
        self._name = f"mem{next(self._ids)}"
        self._decls: list[_Decl] = []

    def _declare(self, keyexpr: str, on_close: Callable[[], None]) -> _Decl:
        decl = _Decl(keyexpr, self, on_close)
        self._decls.append(decl)
        return decl

    def publish(self, key: str, payload: bytes, *, reliable: bool = True) -> None:
        # One transmission per node that subscribes, handed to each of its matching
        # subscriptions there (as a Zenoh session does): a node that subscribes twice,
        # say to record, changes neither what crosses the radio nor its random draws.
        inboxes: dict[str, list[Inbox[Sample]]] = {}
        for decl, inbox in self._net.subscribed(key):
            inboxes.setdefault(decl.owner.node, []).append(inbox)
        sample = Sample(key, bytes(payload))
        for node, there in inboxes.items():
            self._net.carry(self.node, node, functools.partial(_put_all, there, sample), key)

    def subscribe(
        self, keyexpr: str, handler: SampleHandler, *, latest_only: bool = False, maxsize: int = 1024
    ) -> _Decl:
        inbox: Inbox[Sample] = Inbox(
            asyncio.get_running_loop(), handler, name=f"{self._name} sub {keyexpr}",
            latest_only=latest_only, maxsize=maxsize,
        )
        entry: tuple[_Decl, Inbox[Sample]]

        def close() -> None:
            inbox.close()
            self._net.remove_subscriber(entry)

        entry = (self._declare(keyexpr, close), inbox)
        self._net.add_subscriber(entry)
        return entry[0]

    def serve(self, keyexpr: str, handler: QueryHandler) -> _Decl:
        entry: tuple[_Decl, QueryHandler]

        def close() -> None:
            self._net.remove_queryable(entry)
            self._net.reconsider_routes()

        entry = (self._declare(keyexpr, close), handler)
        self._net.add_queryable(entry)
        self._net.reconsider_routes()
        return entry[0]

    def watch_route(self, key: str, handler: RouteHandler) -> _Decl:
        loop = asyncio.get_running_loop()
        told = self._net.routed(self.node, key)

        def check() -> None:
            nonlocal told
            routed = self._net.routed(self.node, key)
            if routed != told:
                told = routed
                loop.call_soon(lambda: None if decl.closed else handler(routed))

        decl = self._declare(key, lambda: self._net.routes.remove(check))
        self._net.routes.append(check)
        handler(told)
        return decl

    async def query(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> bytes:
        return (await self.query_linked(selector, payload, timeout_s=timeout_s))[0]

    async def query_linked(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> tuple[bytes, bool | None]:
        key = strip_parameters(selector)
        net = self._net
        matches = [(d, h) for d, h in net.served(key) if net.reachable(self.node, d.owner.node)]
        if not matches:
            raise NoRoute(f"no queryable for {key}")
        decl, handler = matches[0]
        path = net.medium.path(self.node, decl.owner.node) if net.medium is not None else None
        reply = await self._query(decl, handler, key, selector, payload, timeout_s)
        # the path the reply takes back, as it is when the reply arrives
        back = net.medium.path(decl.owner.node, self.node) if net.medium is not None else None
        return reply, (None if path is None or back is None else len(path) <= 2 and len(back) <= 2)

    async def _query(self, decl: _Decl, handler: QueryHandler, key: str, selector: str, payload: bytes,
                     timeout_s: float) -> bytes:
        net = self._net
        name = decl.keyexpr if "*" not in decl.keyexpr else key
        if "?" in selector:  # the handler sees the parameters, as Zenoh's query.selector
            name += selector[selector.index("?"):]
        if net.medium is None or decl.owner.node == self.node:
            try:
                async with asyncio.timeout(timeout_s):
                    return await handler(name, bytes(payload))
            except TimeoutError:
                raise QueryTimeout(f"no reply from {key} within {timeout_s:g} s") from None
            except Exception as exc:  # an error reply, as Zenoh's reply_err
                raise QueryRefused(f"{key}: {exc}") from None
        return await self._remote_query(net.medium, decl.owner.node, key, name, handler, bytes(payload), timeout_s)

    async def _remote_query(self, medium: Medium, there: str, key: str, name: str,
                            handler: QueryHandler, payload: bytes, timeout_s: float) -> bytes:
        """Across the Medium: the request and the reply each cross it, and the asker
        gives up after `timeout_s` on the Medium's clock. The queryable, once reached,
        runs to its end whether or not its reply makes it back, as on Zenoh; one the
        asker gave up on before its request arrived is never called.

        Callbacks on the Medium's clock, one task (the handler's) per query: the link
        probes of a fast-time fleet are most of its queries, and three tasks and four
        awaits each were an eighth of a relay world's profile samples."""
        net = self._net
        loop = asyncio.get_running_loop()
        outcome: asyncio.Future[bytes] = loop.create_future()

        def replied(reply: bytes | None, error: Exception | None) -> None:
            if outcome.done():
                return
            if error is not None:
                outcome.set_exception(QueryRefused(f"{key}: {error}"))
            else:
                assert reply is not None
                outcome.set_result(reply)

        def answered(task: asyncio.Task[tuple[bytes | None, Exception | None]]) -> None:
            net.answering.discard(task)
            if not task.cancelled():
                reply, error = task.result()
                net.carry(there, self.node, lambda: replied(reply, error), key)

        async def answer() -> tuple[bytes | None, Exception | None]:
            try:
                return await handler(name, payload), None
            except Exception as exc:  # an error reply, as Zenoh's reply_err
                return None, exc

        def arrived() -> None:
            if not outcome.done():
                task = loop.create_task(answer())
                net.answering.add(task)  # the loop holds tasks weakly
                task.add_done_callback(answered)

        def expire() -> None:  # on the Medium's clock: a timer, not a task per query
            if not outcome.done():
                outcome.set_exception(QueryTimeout(f"no reply from {key} within {timeout_s:g} s"))

        net.carry(self.node, there, arrived, key)
        medium.call_later(timeout_s, expire)
        return await outcome

    def announce(self, key: str) -> _Decl:
        def close() -> None:
            self._net.tokens.remove(decl)
            self._net._tell_watchers(decl, False)

        decl = self._declare(key, close)
        self._net.tokens.append(decl)
        self._net._tell_watchers(decl, True)
        return decl

    def watch_links(self, on_closed: Callable[[], None]) -> _Decl:
        decl = self._declare("", lambda: None)
        medium = self._net.medium
        if medium is None:
            return decl  # one node: no links
        held = medium.linked(self.node)

        def check() -> None:
            nonlocal held
            now = medium.linked(self.node)
            closed, held = held - now, now
            if closed and not decl.closed:
                medium.call_later(0.0, lambda: None if decl.closed else on_closed())

        medium.on_change(check)
        return decl

    def watch_liveliness(self, keyexpr: str, handler: LivelinessHandler) -> _Decl:
        inbox: Inbox[tuple[str, bool]] = Inbox(
            asyncio.get_running_loop(), lambda item: handler(*item),
            name=f"{self._name} liveliness {keyexpr}", maxsize=4096,
        )
        entry: tuple[_Decl, Inbox[tuple[str, bool]]]

        def close() -> None:
            inbox.close()
            self._net.watchers.remove(entry)
            self._net._seen.pop(entry[0], None)

        entry = (self._declare(keyexpr, close), inbox)
        self._net.watchers.append(entry)
        for token in self._net.tokens:
            if intersects(keyexpr, token.keyexpr) and self._net.reachable(token.owner.node, self.node):
                self._net._tell(entry, token, True)
        return entry[0]

    async def close(self) -> None:
        for decl in reversed(self._decls):
            decl.close()
        self._decls.clear()


def _put_all(inboxes: list[Inbox[Sample]], sample: Sample) -> None:
    for inbox in inboxes:
        inbox.put_nowait(sample)
