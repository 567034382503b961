"""The Bus port: what every component needs from a pub/sub + query mesh.

Handlers always run on the asyncio event loop of the component that registered
them, never on transport threads, so domain code needs no locks. Subscriptions are
bounded: `latest_only` ones (telemetry) drop the oldest sample when the consumer
lags; the others keep everything up to a large bound and log loudly past it.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Literal, Protocol

from dronefleet.schemas.errors import FleetError


@dataclass(frozen=True, slots=True)
class Sample:
    key: str
    payload: bytes
    kind: Literal["put", "delete"] = "put"


SampleHandler = Callable[[Sample], None]
QueryHandler = Callable[[str, bytes], Awaitable[bytes]]
LivelinessHandler = Callable[[str, bool], None]
RouteHandler = Callable[[bool], None]


async def echo(key: str, payload: bytes) -> bytes:
    """The ping queryables' handler (`ground/ping`, `drone/<id>/ping`): the request back."""
    return payload


class BusError(FleetError):
    """Something went wrong on the message bus."""


class Unreachable(BusError):
    """Nobody answered a query: no queryable matches (the drone is not there)."""


class NoRoute(Unreachable):
    """No queryable matches the key here and now: the drone is not there, or its
    declaration has not reached this node yet (a drone that just registered through
    a neighbour)."""


class QueryTimeout(Unreachable):
    """A queryable exists but did not answer in time."""


class QueryRefused(BusError):
    """The queryable answered with an error reply."""


class Declaration(Protocol):
    def close(self) -> None: ...


class Bus(Protocol):
    def publish(self, key: str, payload: bytes, *, reliable: bool = True) -> None:
        """Send one sample. Unreliable (telemetry) may be dropped under congestion."""

    def subscribe(
        self, keyexpr: str, handler: SampleHandler, *, latest_only: bool = False, maxsize: int = 1024
    ) -> Declaration: ...

    def serve(self, keyexpr: str, handler: QueryHandler) -> Declaration:
        """Answer queries on `keyexpr`; the handler gets the query's key (with
        `?parameters` when the selector had any) and payload, and returns the reply."""

    async def query(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> bytes:
        """The first reply, or Unreachable / QueryTimeout / QueryRefused."""

    async def query_linked(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> tuple[bytes, bool | None]:
        """As `query`, and whether the node that answered is linked to this one directly
        (its reply crossed one link, not a path through other nodes); None: unknown."""

    def announce(self, key: str) -> Declaration:
        """Declare a liveliness token; it vanishes when closed or when this node dies."""

    def watch_liveliness(self, keyexpr: str, handler: LivelinessHandler) -> Declaration:
        """handler(key, alive) for current tokens, then for every appearance/loss."""

    def watch_route(self, key: str, handler: RouteHandler) -> Declaration:
        """handler(routed): whether a query on `key` from here finds a queryable, told
        at once (in this call) and then on every change (on the event loop). This node's
        own routing table answers, so it costs no traffic: a drone heard here whose
        command queryable's declaration has not reached this node is not routed."""

    def watch_links(self, on_closed: Callable[[], None]) -> Declaration:
        """on_closed() (on the event loop) each time a link of this session's node to
        another node closes: the mesh may route its traffic another way from now."""

    async def close(self) -> None: ...
