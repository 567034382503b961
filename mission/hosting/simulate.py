"""Fast-time simulation's product (SPEC §5): the rows of result.json and its plots.

The run itself — the same GroundStation, mission runtime and agents as in the field on
a memory bus under a VirtualClock — is wired in the composition root
(`dronefleet.compose.SimField`); this module says what a run writes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgspec

from dronefleet.mission.lifecycle.record import MissionRecord
from dronefleet.schemas.telemetry import LinkQuality, SensorReading, Telemetry


class SampledLink(msgspec.Struct, frozen=True, kw_only=True):
    quality: float
    rtt_ms: float | None
    loss: float | None


class Sample(msgspec.Struct, frozen=True, kw_only=True):
    """One row of a drone's time series in result.json (SPEC §5), written by the
    simulator and read by the ground's preflight (`SimResult`)."""

    t_s: float
    lat: float
    lon: float
    alt: float
    rel_alt: float
    heading: float
    speed: float
    battery: float | None  # remaining, 0-1
    state: str  # the ground's state of the drone then
    armed: bool
    sensors: dict[str, Any]
    link: SampledLink | None  # the drone's last measured link to the ground (SPEC §8)


class Track(msgspec.Struct, frozen=True, kw_only=True):
    samples: list[Sample]


class UnknownRead(msgspec.Struct, frozen=True, kw_only=True):
    """A prediction's first read of what its world cannot know (SimField `predicting`)."""

    line: int | None  # the script's; None when a plugin read it
    what: str


class SimResult(msgspec.Struct, frozen=True, kw_only=True):
    """What of result.json a reader types: the mission's record and each drone's
    samples (the rest, for plots and lanes, stays as written)."""

    mission: MissionRecord
    drones: dict[str, Track]
    unknown: UnknownRead | None = None


def telemetry_sample(t: Telemetry, t_s: float, state: str, sensors: dict[str, Any],
                     link: LinkQuality | None = None) -> dict[str, Any]:
    """One row of a drone's time series in result.json (a `Sample`); `link` is absent
    before the drone's first probe."""
    assert t.position is not None
    sample = Sample(
        t_s=round(t_s, 3),
        lat=round(t.position.lat, 8), lon=round(t.position.lon, 8),
        alt=round(t.position.alt, 3), rel_alt=round(t.position.rel_alt, 3),
        heading=round(t.heading, 2), speed=round(t.speed, 3),
        battery=round(t.battery.remaining_percent, 5) if t.battery else None,
        state=state, armed=t.armed, sensors=sensors,
        link=None if link is None else SampledLink(quality=link.quality, rtt_ms=link.rtt_ms, loss=link.loss),
    )
    row: dict[str, Any] = msgspec.to_builtins(sample)
    return row


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
