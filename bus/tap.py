"""Watch the mesh: every sample (and liveliness change) under a key expression,
formatted as one readable line each. Backs `fleet sub`."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import msgspec

from dronefleet.bus.port import Sample
from dronefleet.bus.zenoh_bus import ZenohBus


def format_sample(sample: Sample) -> str:
    if sample.kind == "delete":
        return f"{sample.key} (deleted)"
    try:
        body = msgspec.json.encode(msgspec.json.decode(sample.payload)).decode()
    except msgspec.DecodeError:
        body = repr(sample.payload[:200])
    return f"{sample.key} {body}"


async def tap(keyexpr: str, connect: list[str], out: Callable[[str], None], count: int | None = None,
              extra: dict[str, Any] | None = None) -> None:
    bus = await ZenohBus.open("client", connect, extra=extra)
    done = asyncio.Event()
    seen = 0

    def on_sample(sample: Sample) -> None:
        nonlocal seen
        out(format_sample(sample))
        seen += 1
        if count is not None and seen >= count:
            done.set()

    try:
        bus.subscribe(keyexpr, on_sample, maxsize=10_000)
        bus.watch_liveliness(keyexpr, lambda key, alive: out(f"{key} {'ALIVE' if alive else 'DROPPED'}"))
        await done.wait()
    finally:
        await bus.close()
