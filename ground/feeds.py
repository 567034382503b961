"""What the station hears besides telemetry and statuses (SPEC §2): what each drone
says it is (About on `drone/<id>/about`, asked of its agent when the ground missed it)
and the field sensors (`sensor/<id>/<type>`, liveliness `sensor/<id>/alive`).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Protocol

import msgspec

from dronefleet.bus.clock import Clock
from dronefleet.bus.port import Bus, Declaration, QueryRefused, Sample, Unreachable
from dronefleet.ground.describe import Level
from dronefleet.ground.inbound import Inbound
from dronefleet.ground.registry import Event, LogLine, Registry
from dronefleet.schemas.about import About
from dronefleet.schemas.codec import decode_about, decode_sensor
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.fleet import WatchEvent
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import SensorReading

log = logging.getLogger(__name__)
ABOUT_ASK_S = 30.0  # a registered drone whose About was not heard is asked this often
# Ids not registered (past the registry's bounds) are asked only while fewer than this
# many asks are out, and remembered only this many at once: a flood of made-up ids on an
# open mesh costs a bounded number of queries and entries, not one per id.
UNREGISTERED_ASKS = 16
ASKED_KEPT = 4096


class FeedsOut(Protocol):
    """Where what the feeds learn goes (the station)."""

    def emit(self, events: list[Event]) -> None:
        """Registry events: log lines and drone changes, to the log and every watcher."""

    def broadcast(self, event: WatchEvent) -> None:
        """To the watchers (HTTP event streams)."""

    def tell(self, event: WatchEvent) -> None:
        """To the missions."""


class SensorFeeds:
    def __init__(self, bus: Bus, keys: Keys, clock: Clock, registry: Registry, inbound: Inbound, *,
                 query_timeout_s: float, out: FeedsOut) -> None:
        self.bus, self.keys, self.clock, self.registry, self.inbound = bus, keys, clock, registry, inbound
        self.query_timeout_s = query_timeout_s
        self.out = out
        self._about_asked: dict[str, float] = {}  # drone → when its About was last asked for (monotonic)
        self._asking: set[asyncio.Task[None]] = set()

    def declare(self) -> list[Declaration]:
        bus, k = self.bus, self.keys
        return [
            bus.subscribe(k.about(), self._on_about, maxsize=1024),
            bus.subscribe(k.field_sensor(), self._on_field_reading, latest_only=True, maxsize=4096),
            bus.watch_liveliness(k.field_sensor_alive(), self._on_field_liveliness),
        ]

    # ---- About ---------------------------------------------------------------------

    def _on_about(self, sample: Sample) -> None:
        about: About | None = self.inbound.from_drone(decode_about, sample)
        if about is not None:
            self.out.emit(self.registry.on_about(about, self.clock.time_ms()))

    def ask_about(self, drone_id: str) -> None:
        """A drone heard without its About (the ground started after it, the publication
        was lost, or it is not registered for want of one): ask its agent, at most every
        ABOUT_ASK_S; one not registered only while few asks are out (UNREGISTERED_ASKS)."""
        now = self.clock.monotonic()
        if self.registry.about(drone_id) is not None or now - self._about_asked.get(drone_id, -1e9) < ABOUT_ASK_S:
            return
        if drone_id not in self.registry and len(self._asking) >= UNREGISTERED_ASKS:
            return
        if len(self._about_asked) >= ASKED_KEPT:  # forget those asked longest ago
            self._about_asked = {d: t for d, t in self._about_asked.items() if now - t < ABOUT_ASK_S}
            if len(self._about_asked) >= ASKED_KEPT:
                return
        self._about_asked[drone_id] = now

        async def ask() -> None:
            try:
                raw = await self.bus.query(self.keys.about(drone_id), timeout_s=self.query_timeout_s)
                about = msgspec.structs.replace(decode_about(raw), drone_id=drone_id)
            except (Unreachable, QueryRefused, InvalidMessage) as exc:
                log.info("%s: no About from its agent (%s); asked again in %g s", drone_id, exc, ABOUT_ASK_S)
                return
            self.out.emit(self.registry.on_about(about, self.clock.time_ms()))

        task = asyncio.get_running_loop().create_task(ask(), name=f"about {drone_id}")
        self._asking.add(task)
        task.add_done_callback(self._asking.discard)

    # ---- field sensors -------------------------------------------------------------

    def _on_field_reading(self, sample: Sample) -> None:
        parsed = self.keys.parse_field_sensor(sample.key)
        reading: SensorReading | None = self.inbound.decode(decode_sensor, sample)
        if parsed is None or reading is None:
            return
        sensor_id, kind = parsed
        # The key is the authority (on a secured mesh only that sensor may publish under it).
        reading = msgspec.structs.replace(reading, sensor_id=sensor_id, type=kind)
        lines, kept = self.registry.field.on_reading(reading, self.clock.time_ms())
        self._log(lines)
        if kept is not None:
            event = WatchEvent("field_sensor", kept)
            self.out.broadcast(event)
            self.out.tell(event)

    def _on_field_liveliness(self, key: str, alive: bool) -> None:
        parts = key.split("/")
        if len(parts) >= 3 and parts[-1] == "alive":
            self._log(self.registry.field.on_liveliness(parts[-2], alive))

    def tick(self) -> None:
        lines, gone = self.registry.field.tick(self.clock.time_ms())
        self._log(lines)
        for sensor_id, kind in gone:
            self.out.tell(WatchEvent("field_sensor_lost", {"sensor_id": sensor_id, "type": kind}))

    def _log(self, lines: list[tuple[Level, str]]) -> None:
        now = self.clock.time_ms()
        self.out.emit([LogLine(timestamp=now, level=level, drone_id=None, message=message) for level, message in lines])
