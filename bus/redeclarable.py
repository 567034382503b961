"""A queryable declared afresh without a moment undeclared (ADR 0003).

The agent's command and bundle queryables are refreshed after a contact gap: the mesh
may have routed the drone another way without carrying their declarations over it.
"""

from __future__ import annotations

import asyncio
import math

from dronefleet.bus.clock import Clock
from dronefleet.bus.port import Bus, Declaration, QueryHandler

OVERLAP_S = 1.0  # after a fresh declaration: a query reaching both gets one answer, within this


class Redeclarable:
    """A queryable that can be declared afresh without a moment undeclared.

    After the mesh routed a drone another way, the ground's router could hold no route
    to its `cmd` queryable while its telemetry flowed (twice in 5 real-packet runs of
    one corpus world, ADR 0003): a declaration is not always carried again over the new
    way. `refresh` declares the other of two forms that match the same key (`K`, then
    `K/**`, a new resource to every router, so it travels the mesh anew), then
    undeclares the old one. While both are declared a query can reach both: for
    OVERLAP_S after a refresh the same query (selector and payload) gets the first
    answer again instead of a second run. Only then: a replayed command is otherwise
    refused as one (SPEC §9), and within that second it is not run twice either.
    """

    def __init__(self, bus: Bus, key: str, handler: QueryHandler, clock: Clock) -> None:
        self._bus, self._handler, self._clock = bus, handler, clock
        self._forms = (key, f"{key}/**")
        self.refreshes = 0
        self._refreshed_at = -math.inf
        self._answers: dict[tuple[str, bytes], tuple[float, asyncio.Future[bytes]]] = {}
        self._declared: Declaration = bus.serve(key, self._answer)

    @property
    def form(self) -> str:
        return self._forms[self.refreshes % 2]

    async def _answer(self, selector: str, payload: bytes) -> bytes:
        now = self._clock.monotonic()
        for query in [q for q, (at, _) in self._answers.items() if now - at > OVERLAP_S]:
            del self._answers[query]
        if now - self._refreshed_at > OVERLAP_S:
            return await self._handler(selector, payload)
        known = self._answers.get((selector, payload))
        if known is not None:
            return await asyncio.shield(known[1])
        answer: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        self._answers[(selector, payload)] = (now, answer)
        try:
            answer.set_result(await self._handler(selector, payload))
        except BaseException as exc:
            answer.set_exception(exc)
            answer.exception()  # retrieved: a duplicate awaiting it gets it, none is no warning
            del self._answers[(selector, payload)]  # an error is not remembered: a retry runs again
            raise
        return answer.result()

    def refresh(self) -> None:
        self.refreshes += 1
        self._refreshed_at = self._clock.monotonic()
        fresh = self._bus.serve(self.form, self._answer)
        self._declared.close()
        self._declared = fresh

    def close(self) -> None:
        self._declared.close()
