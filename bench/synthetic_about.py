"""Synthetic drones say what they are, as agents do: an About published for each, and the
ground's ask answered (`drone/*/about`). The ground registers an id whose About it heard
at once; others only from its bucket of unannounced ids (ground/registry.py)."""

from __future__ import annotations

import time
from collections.abc import Iterable

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.about import About
from dronefleet.schemas.codec import encode
from dronefleet.schemas.keys import Keys


def _about(drone_id: str) -> bytes:
    return encode(About(drone_id=drone_id, timestamp=time.time_ns() // 1_000_000))


async def _answer(key: str, payload: bytes) -> bytes:
    return _about(key.split("/")[-2])  # drone/<id>/about


def announce(bus: ZenohBus, drone_ids: Iterable[str], keys: Keys | None = None) -> None:
    """Publish each drone's About and answer the ground's asks for any of them."""
    keys = keys or Keys()
    bus.serve(keys.about("*"), _answer)
    for drone_id in drone_ids:
        bus.publish(keys.about(drone_id), _about(drone_id))
