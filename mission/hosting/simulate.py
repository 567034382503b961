"""Fast-time simulation's product (SPEC §5): the rows of result.json and its plots.

The run itself — the same GroundStation, mission runtime and agents as in the field on
a memory bus under a VirtualClock — is wired in the composition root
(`dronefleet.compose.SimField`); this module says what a run writes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from dronefleet.schemas.telemetry import LinkQuality, SensorReading, Telemetry


def telemetry_sample(t: Telemetry, t_s: float, state: str, sensors: dict[str, Any],
                     link: LinkQuality | None = None) -> dict[str, Any]:
    """One row of a drone's time series in result.json (SPEC §5); `link` is the drone's
    last measured link to the ground (SPEC §8), absent before its first probe."""
    assert t.position is not None
    return {
        "t_s": round(t_s, 3),
        "lat": round(t.position.lat, 8), "lon": round(t.position.lon, 8),
        "alt": round(t.position.alt, 3), "rel_alt": round(t.position.rel_alt, 3),
        "heading": round(t.heading, 2), "speed": round(t.speed, 3),
        "battery": round(t.battery.remaining_percent, 5) if t.battery else None,
        "state": state, "armed": t.armed, "sensors": sensors,
        "link": None if link is None else {"quality": link.quality, "rtt_ms": link.rtt_ms, "loss": link.loss},
    }


def sensor_values(readings: list[SensorReading]) -> dict[str, Any]:
    """A drone's latest readings as a sample's `sensors`: type → value, or its fields."""
    return {r.type: r.data for r in readings}


def add_field_reading(rows: dict[str, dict[str, Any]], reading: SensorReading, t_s: float) -> None:
    """result.json's `field_sensors`: per field sensor where it stands and what it read
    (`{"gas07": {"lat", "lon", "readings": [{"t_s", "type", "value"}]}}`)."""
    if reading.position is None or not reading.sensor_id:
        return
    row = rows.setdefault(reading.sensor_id, {"lat": reading.position.lat, "lon": reading.position.lon, "readings": []})
    row["lat"], row["lon"] = reading.position.lat, reading.position.lon
    row["readings"].append({"t_s": round(t_s, 3), "type": reading.type,
                            "value": reading.data})


def write_result(result: dict[str, Any], out_dir: Path, plots: bool) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "result.json").write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    if plots:
        from dronefleet.mission.hosting.plots import write_plots

        write_plots(result, out_dir)
