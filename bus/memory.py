"""In-process Bus with Zenoh's semantics, for unit tests and fast-time simulation.

A MemoryNetwork plays the router; each MemoryBus is one session on it. Samples
travel through the same bounded Inbox as on Zenoh, a get with no matching
queryable ends at once, a slow queryable times out, and closing a session drops
its liveliness tokens as a dead node's would.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

from bus.delivery import Inbox
from bus.keyexpr import intersects, strip_parameters
from bus.port import (
    LivelinessHandler,
    QueryHandler,
    QueryRefused,
    QueryTimeout,
    Sample,
    SampleHandler,
    Unreachable,
)


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
    """The shared medium: every declaration of every session, by kind."""

    subscribers: list[tuple[_Decl, Inbox[Sample]]] = field(default_factory=list)
    queryables: list[tuple[_Decl, QueryHandler]] = field(default_factory=list)
    tokens: list[_Decl] = field(default_factory=list)
    watchers: list[tuple[_Decl, Inbox[tuple[str, bool]]]] = field(default_factory=list)

    def _tell_watchers(self, key: str, alive: bool) -> None:
        for decl, inbox in self.watchers:
            if intersects(decl.keyexpr, key):
                inbox.put_nowait((key, alive))


class MemoryBus:
    _ids = itertools.count(1)

    def __init__(self, network: MemoryNetwork) -> None:
        self._net = network
        self._name = f"mem{next(self._ids)}"
        self._decls: list[_Decl] = []

    def _declare(self, keyexpr: str, on_close: Callable[[], None]) -> _Decl:
        decl = _Decl(keyexpr, self, on_close)
        self._decls.append(decl)
        return decl

    def publish(self, key: str, payload: bytes, *, reliable: bool = True) -> None:
        for decl, inbox in list(self._net.subscribers):
            if intersects(decl.keyexpr, key):
                inbox.put_nowait(Sample(key, bytes(payload)))

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
            self._net.subscribers.remove(entry)

        entry = (self._declare(keyexpr, close), inbox)
        self._net.subscribers.append(entry)
        return entry[0]

    def serve(self, keyexpr: str, handler: QueryHandler) -> _Decl:
        entry: tuple[_Decl, QueryHandler]
        entry = (self._declare(keyexpr, lambda: self._net.queryables.remove(entry)), handler)
        self._net.queryables.append(entry)
        return entry[0]

    async def query(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> bytes:
        key = strip_parameters(selector)
        matches = [(d, h) for d, h in self._net.queryables if intersects(d.keyexpr, key)]
        if not matches:
            raise Unreachable(f"no queryable for {key}")
        decl, handler = matches[0]
        try:
            async with asyncio.timeout(timeout_s):
                return await handler(decl.keyexpr if "*" not in decl.keyexpr else key, bytes(payload))
        except TimeoutError:
            raise QueryTimeout(f"no reply from {key} within {timeout_s:g} s") from None
        except Exception as exc:  # an error reply, as Zenoh's reply_err
            raise QueryRefused(f"{key}: {exc}") from None

    def announce(self, key: str) -> _Decl:
        def close() -> None:
            self._net.tokens.remove(decl)
            self._net._tell_watchers(key, False)

        decl = self._declare(key, close)
        self._net.tokens.append(decl)
        self._net._tell_watchers(key, True)
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

        entry = (self._declare(keyexpr, close), inbox)
        self._net.watchers.append(entry)
        for token in self._net.tokens:
            if intersects(keyexpr, token.keyexpr):
                inbox.put_nowait((token.keyexpr, True))
        return entry[0]

    async def close(self) -> None:
        for decl in reversed(self._decls):
            decl.close()
        self._decls.clear()
