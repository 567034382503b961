"""The ground records every mission to `<data_dir>/missions/<id>.mcap` (SPEC §12).

A recording opens when the mission is submitted and closes when it ends. It holds
everything the ground hears on the mesh meanwhile (every drone's messages and
liveliness, not only the mission's drones: the context of a flight), the commands and
bundles the ground sent (`drone/<id>/cmd`, `…/bundle`), the ground's event log
(`ground/log`), and the mission's record and log lines (`ground/mission/<id>`,
`…/log`). Concurrent missions share one subscription.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

from dronefleet.bus.port import Bus
from dronefleet.bus.recording import BusRecording, Contents, Recorder
from dronefleet.ground.config import GroundConfig
from dronefleet.ground.registry import LogLine, Registry
from dronefleet.mission.hosting.simulate import add_field_reading, sensor_values, telemetry_sample
from dronefleet.mission.lifecycle.record import MissionLogLine, MissionRecord
from dronefleet.schemas.codec import decode_link, decode_sensor, decode_status, decode_telemetry
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.fence import Geofence
from dronefleet.schemas.fleet import WatchEvent
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import Telemetry

log = logging.getLogger(__name__)
GROUND_KINDS: dict[str, Any] = {"LogLine": LogLine, "MissionRecord": MissionRecord, "MissionLogLine": MissionLogLine}
ENDED = frozenset({"finished", "failed", "cancelled"})


def recording_metadata(mission_id: str, namespace: str, geofence: Geofence,
                       ground_station: tuple[float, float] | None = None) -> dict[str, str]:
    """What `fleet plot` needs besides the messages (MCAP metadata `fleet`)."""
    meta = {"mission_id": mission_id, "namespace": namespace}
    if geofence.limits:
        meta["geofence"] = msgspec.json.encode(geofence).decode()
    if ground_station is not None:
        meta["ground_station"] = json.dumps({"lat": ground_station[0], "lon": ground_station[1]})
    return meta


class MissionRecordings:
    def __init__(self, bus: Bus, keys: Keys, directory: Path, now_ns: Callable[[], int], geofence: Geofence,
                 ground_station: tuple[float, float] | None = None) -> None:
        self.bus = bus
        self.keys = keys
        self.directory = directory
        self.now_ns = now_ns
        self.geofence = geofence
        self.ground_station = ground_station
        self.open: dict[str, Recorder] = {}
        self._mesh: BusRecording | None = None  # one subscription while any mission records

    def path(self, mission_id: str) -> Path:
        return self.directory / f"{mission_id}.mcap"

    # ---- what the station tells ------------------------------------------------------

    def on_event(self, event: WatchEvent) -> None:
        if event.kind == "mission":
            record = event.data
            mission_id = record["mission_id"]
            if mission_id not in self.open and record["status"] not in ENDED:
                self._start(mission_id)
            recorder = self.open.get(mission_id)
            if recorder is not None:
                recorder.write(self.keys.ground("mission", mission_id), json.dumps(record).encode(),
                               self.now_ns(), "MissionRecord")
                if record["status"] in ENDED:
                    self._finish(mission_id)
        elif event.kind == "mission_log":
            line = dict(event.data)
            recorder = self.open.get(line.pop("mission_id"))
            if recorder is not None:
                recorder.write(self.keys.ground("mission", event.data["mission_id"], "log"),
                               json.dumps(line).encode(), self.now_ns(), "MissionLogLine")
        elif event.kind == "log" and self.open:
            payload = msgspec.json.encode(event.data)
            for recorder in self.open.values():
                recorder.write(self.keys.ground("log"), payload, self.now_ns(), "LogLine")

    def sent(self, key: str, payload: bytes) -> None:
        """A command or bundle the ground sent (a query: no subscriber sees it)."""
        for recorder in self.open.values():
            recorder.write(key, payload, self.now_ns())

    def tick(self) -> None:
        if self._mesh is not None:
            self._mesh.tick()

    def close(self) -> None:
        for mission_id in list(self.open):
            self._finish(mission_id)

    # ---- the files -----------------------------------------------------------------

    def _start(self, mission_id: str) -> None:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            recorder = Recorder(self.path(mission_id), kinds=GROUND_KINDS, metadata=recording_metadata(
                mission_id, self.keys.namespace, self.geofence, self.ground_station))
        except OSError as exc:  # a full disk must not stop the mission
            log.error("cannot record mission %s to %s: %s", mission_id, self.path(mission_id), exc)
            return
        self.open[mission_id] = recorder
        if self._mesh is None:
            self._mesh = BusRecording(self.bus, [recorder], self.keys.everything(), self.now_ns)
        else:
            self._mesh.add(recorder)

    def _finish(self, mission_id: str) -> None:
        recorder = self.open.pop(mission_id)
        assert self._mesh is not None
        self._mesh.remove(recorder)
        try:
            recorder.close()
        except OSError as exc:
            log.error("cannot finish the recording of mission %s: %s", mission_id, exc)
        if not self.open:
            self._mesh.close()
            self._mesh = None
        log.info("mission %s recorded to %s (%d messages)", mission_id, recorder.path, recorder.messages)


def result_of_recording(contents: Contents, config: GroundConfig | None = None) -> dict[str, Any]:
    """A recording as the rows of a simulation's result.json (SPEC §5), for `fleet plot`.

    The messages go through a ground's Registry in the order they were received, so
    each telemetry row carries the state the ground gave the drone at that moment."""
    registry = Registry(config or GroundConfig(data_dir="."))
    meta = contents.metadata
    samples: dict[str, list[dict[str, Any]]] = {}
    mission: dict[str, Any] = {"mission_id": meta.get("mission_id", "-"), "status": "recorded", "cause": None}
    log_lines: list[dict[str, Any]] = []
    field_sensors: dict[str, dict[str, Any]] = {}
    t0 = contents.messages[0].log_ns if contents.messages else 0
    first: Telemetry | None = None
    for message in contents.messages:
        now_ms = message.log_ns // 1_000_000
        registry.tick(now_ms)
        try:
            if message.kind == "Telemetry":
                telem = decode_telemetry(message.data)
                registry.on_telemetry(telem, now_ms)
                first = first or telem
                if telem.position is not None:
                    info = registry.info(telem.drone_id)
                    sensors = sensor_values(registry.sensor_readings(telem.drone_id))
                    samples.setdefault(telem.drone_id, []).append(
                        telemetry_sample(telem, (message.log_ns - t0) / 1e9, info.state, sensors, info.link))
            elif message.kind == "Status":
                registry.on_status(decode_status(message.data), now_ms)
            elif message.kind == "SensorReading":
                reading = decode_sensor(message.data)
                if reading.sensor_id:  # a field sensor (SPEC §2 sensor/<id>/<type>)
                    add_field_reading(field_sensors, reading, (message.log_ns - t0) / 1e9)
                else:
                    registry.on_sensor(reading, now_ms)
            elif message.kind == "LinkQuality":
                registry.on_link(decode_link(message.data), now_ms)
            elif message.kind == "MissionRecord":
                mission = json.loads(message.data)
            elif message.kind == "MissionLogLine":
                log_lines.append(json.loads(message.data))
        except InvalidMessage as exc:
            log.warning("%s at %d ns: %s", message.topic, message.log_ns, exc)
    if "ground_station" in meta:
        ground_station = json.loads(meta["ground_station"])
    elif first is not None and first.home is not None:
        ground_station = {"lat": first.home.lat, "lon": first.home.lon, "label": f"home of {first.drone_id}"}
    else:
        ground_station = {"lat": 0.0, "lon": 0.0}
    return {
        "mission": mission,
        "log": log_lines,
        "t0_ms": t0 // 1_000_000,
        "ground_station": ground_station,
        **({"geofence": json.loads(meta["geofence"])} if "geofence" in meta else {}),
        "drones": {drone_id: {"samples": rows, "commands": []} for drone_id, rows in sorted(samples.items())},
        **({"field_sensors": field_sensors} if field_sensors else {}),
    }
