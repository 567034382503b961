"""A link probe (SPEC §8): what an agent asks `ground/ping` and its neighbours'
`drone/<id>/ping`, and what comes back.

The answer is the probe echoed. The ground adds `redeclare` when it hears the drone
but holds no route to its command queryable (ADR 0003, issue 76): the answer travels
back the way the probe came, which needs no declaration, so it reaches a drone whose
commands cannot.
"""

from __future__ import annotations

import msgspec


class Ping(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    drone_id: str  # who probes
    timestamp: int  # ms since the epoch, the prober's clock
    seq: int
    redeclare: bool = False  # in the ground's answer: declare your command queryables afresh


ping_decoder = msgspec.json.Decoder(Ping)
