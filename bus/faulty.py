"""A Bus that loses what it is told to lose: the seam for tests of what a lost message
does (a reliable publication gone down with a link that closed under it, say).

`FaultyBus(inner, lose=...)` passes everything to `inner` except the publications for
which `lose(key, payload)` is true: those are kept in `lost` and go nowhere; and, with
`lose_serve`, the queryables for which `lose_serve(keyexpr)` is true: declared here,
but no query on the mesh finds them (a declaration that never crossed, ADR 0003), kept
in `lost_serves`. In-process (fast time and unit tests); the real mesh's faults are
made with the emulated radio.
"""

from __future__ import annotations

from collections.abc import Callable

from dronefleet.bus.port import Bus, Declaration, LivelinessHandler, QueryHandler, RouteHandler, SampleHandler


class FaultyBus:
    def __init__(self, inner: Bus, lose: Callable[[str, bytes], bool] = lambda key, payload: False,
                 lose_serve: Callable[[str], bool] = lambda keyexpr: False) -> None:
        self.inner = inner
        self.lose = lose
        self.lose_serve = lose_serve
        self.lost: list[tuple[str, bytes]] = []
        self.lost_serves: list[str] = []

    def publish(self, key: str, payload: bytes, *, reliable: bool = True) -> None:
        if self.lose(key, payload):
            self.lost.append((key, payload))
            return
        self.inner.publish(key, payload, reliable=reliable)

    def subscribe(self, keyexpr: str, handler: SampleHandler, *, latest_only: bool = False,
                  maxsize: int = 1024) -> Declaration:
        return self.inner.subscribe(keyexpr, handler, latest_only=latest_only, maxsize=maxsize)

    def serve(self, keyexpr: str, handler: QueryHandler) -> Declaration:
        if self.lose_serve(keyexpr):
            self.lost_serves.append(keyexpr)
            return _Nothing()
        return self.inner.serve(keyexpr, handler)

    async def query(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> bytes:
        return await self.inner.query(selector, payload, timeout_s=timeout_s)

    async def query_linked(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> tuple[bytes, bool | None]:
        return await self.inner.query_linked(selector, payload, timeout_s=timeout_s)

    def announce(self, key: str) -> Declaration:
        return self.inner.announce(key)

    def watch_liveliness(self, keyexpr: str, handler: LivelinessHandler) -> Declaration:
        return self.inner.watch_liveliness(keyexpr, handler)

    def watch_route(self, key: str, handler: RouteHandler) -> Declaration:
        return self.inner.watch_route(key, handler)

    def watch_links(self, on_closed: Callable[[], None]) -> Declaration:
        return self.inner.watch_links(on_closed)

    async def close(self) -> None:
        await self.inner.close()


class _Nothing:
    def close(self) -> None:
        pass
