"""Messages from the mesh, decoded as the ground takes them: a bad one is a throttled
warning naming its key (issue 31), never an exception; a drone's message speaks for the
drone its key names (the key is the authority: on a secured mesh only that drone may
publish under it, and a sensor program may leave the field empty)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, TypeVar

import msgspec

from dronefleet.bus.clock import Clock
from dronefleet.bus.port import Sample
from dronefleet.ground.throttle import WarningThrottle
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.keys import Keys

log = logging.getLogger("dronefleet.ground.station")
M = TypeVar("M")


class Inbound:
    def __init__(self, keys: Keys, clock: Clock) -> None:
        self.keys = keys
        self.warnings = WarningThrottle(log, clock)

    def decode(self, decoder: Callable[[bytes], M], sample: Sample) -> M | None:
        try:
            return decoder(sample.payload)
        except InvalidMessage as exc:
            self.warnings.warn(sample.key, "ignored a bad message on %s: %s", sample.key, exc)
            return None

    def from_drone(self, decoder: Callable[[bytes], Any], sample: Sample) -> Any:
        """A drone's message (with a `drone_id`), its drone_id taken from the key."""
        message = self.decode(decoder, sample)
        parsed = self.keys.parse(sample.key)
        if message is None or parsed is None:
            return None
        if message.drone_id != parsed.drone_id:
            message = msgspec.structs.replace(message, drone_id=parsed.drone_id)
        return message
