"""The plots of a simulation result (SPEC §5), drawn with matplotlib (Agg): paths,
altitude, battery, distances and, where links were measured, link quality; where field
sensors were heard, they stand on the paths (magenta diamonds) and `sensors.png` draws
their readings beside the drones' readings of the same types."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

from dronefleet.schemas.geo import distance_m
from dronefleet.sim.projection import LocalFrame


def write_plots(result: dict[str, Any], out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    gs = result["ground_station"]
    frame = LocalFrame(gs["lat"], gs["lon"])
    drones = {k: v["samples"] for k, v in result["drones"].items() if v["samples"]}
    title = f"mission {result['mission']['mission_id']}: {result['mission']['status']} ({result['mission']['cause']})"
    written = []

    def save(fig: Any, name: str) -> None:
        path = out_dir / name
        fig.savefig(path, dpi=110, metadata={"Software": None})
        plt.close(fig)
        written.append(path)

    fig, ax = plt.subplots(figsize=(7, 7))
    for drone_id, samples in drones.items():
        north_east = [frame.to_local(s["lat"], s["lon"]) for s in samples]
        ax.plot([e for _, e in north_east], [n for n, _ in north_east], label=drone_id, linewidth=1.5)
        colour = ax.lines[-1].get_color()
        ax.plot(north_east[0][1], north_east[0][0], "o", color=colour)
        flown = [frame.to_local(s["lat"], s["lon"]) for s in result["drones"][drone_id].get("flown", ())]
        if flown:  # on the radio: the path flown, also where the ground did not hear it
            ax.plot([e for _, e in flown], [n for n, _ in flown], linestyle=":", color=colour, linewidth=1,
                    label=f"{drone_id} flown (heard or not)")
    ax.plot(0, 0, "k^", markersize=10, label=gs.get("label", "ground station"))
    field_sensors = result.get("field_sensors") or {}
    for sensor_id, sensor in sorted(field_sensors.items()):
        north, east = frame.to_local(sensor["lat"], sensor["lon"])
        types = sorted({r["type"] for r in sensor["readings"]})
        ax.plot(east, north, "D", color=FIELD_SENSOR_COLOUR, markersize=9,
                label=f"field sensor {sensor_id} ({', '.join(types)})")
        ax.annotate(sensor_id, (east, north), textcoords="offset points", xytext=(6, 6), color=FIELD_SENSOR_COLOUR)
    fence = (result.get("geofence") or {}).get("polygon")
    if fence:
        corners = [frame.to_local(lat, lon) for lat, lon in [*fence, fence[0]]]
        ax.plot([e for _, e in corners], [n for n, _ in corners], color="tab:red", linestyle="--", linewidth=1.5,
                label="geofence")
    ax.set(xlabel="east (m)", ylabel="north (m)", title=f"paths - {title}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend()
    save(fig, "paths.png")

    for key, label, name in (("rel_alt", "altitude above home (m)", "altitude.png"), ("battery", "battery (0-1)", "battery.png")):
        fig, ax = plt.subplots(figsize=(8, 4))
        for drone_id, samples in drones.items():
            ax.plot([s["t_s"] for s in samples], [s[key] if s[key] is not None else float("nan") for s in samples], label=drone_id)
        ax.set(xlabel="time (s)", ylabel=label, title=title)
        ax.grid(True, alpha=0.3)
        ax.legend()
        save(fig, name)

    # Distances on the paths flown where the radio is simulated (heard samples of two
    # drones rarely share a time), else on what the ground heard.
    paths = {k: result["drones"][k].get("flown") or v for k, v in drones.items()}
    fig, ax = plt.subplots(figsize=(8, 4))
    for drone_id, samples in paths.items():
        ax.plot([s["t_s"] for s in samples], [distance_m(s["lat"], s["lon"], gs["lat"], gs["lon"]) for s in samples],
                label=f"{drone_id} - ground")
    for a, b in itertools.combinations(sorted(paths), 2):
        by_t = {s["t_s"]: s for s in paths[b]}
        pairs = [(s, by_t[s["t_s"]]) for s in paths[a] if s["t_s"] in by_t]
        ax.plot([s["t_s"] for s, _ in pairs], [distance_m(s["lat"], s["lon"], o["lat"], o["lon"]) for s, o in pairs],
                linestyle="--", label=f"{a} - {b}")
    ax.set(xlabel="time (s)", ylabel="distance (m)", title=title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    save(fig, "distances.png")

    linked = {k: [s for s in v if s.get("link")] for k, v in drones.items()}
    if any(linked.values()):  # SPEC §8: each drone's measured link to the ground
        fig, ax = plt.subplots(figsize=(8, 4))
        for drone_id, samples in linked.items():
            if samples:
                ax.plot([s["t_s"] for s in samples], [s["link"]["quality"] for s in samples], label=drone_id)
        ax.set(xlabel="time (s)", ylabel="measured link quality to the ground (0-1)", ylim=(-0.05, 1.05), title=title)
        ax.grid(True, alpha=0.3)
        ax.legend()
        save(fig, "link.png")

    series = _sensor_series(result)
    if field_sensors and series:
        fig, axes = plt.subplots(len(series), 1, figsize=(8, 3.2 * len(series)), squeeze=False)
        for ax, (kind, lines) in zip(axes[:, 0], sorted(series.items()), strict=True):
            for (source, name), points in sorted(lines.items()):
                on_field = source in field_sensors
                ax.plot([t for t, _ in points], [v for _, v in points], label=f"{source} {name}",
                        linestyle="-" if on_field else "--", marker="D" if on_field else None, markersize=3)
            ax.set(xlabel="time (s)", ylabel=kind, title=f"{kind} readings - {title}")
            ax.grid(True, alpha=0.3)
            ax.legend()
        fig.tight_layout()
        save(fig, "sensors.png")
    return written


FIELD_SENSOR_COLOUR = "#ff00ff"  # magenta: no drone's line takes it


def _sensor_series(result: dict[str, Any]) -> dict[str, dict[tuple[str, str], list[tuple[float, float]]]]:
    """Per sensor type, per (field sensor or drone, field): the numeric readings over time."""
    series: dict[str, dict[tuple[str, str], list[tuple[float, float]]]] = {}

    def add(kind: str, source: str, t_s: float, value: Any) -> None:
        values = value if isinstance(value, dict) else {kind: value}
        for name, v in values.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                series.setdefault(kind, {}).setdefault((source, name), []).append((t_s, float(v)))

    for sensor_id, sensor in (result.get("field_sensors") or {}).items():
        for r in sensor["readings"]:
            add(r["type"], sensor_id, r["t_s"], r["value"])
    kinds = set(series)
    for drone_id, drone in result["drones"].items():
        for s in drone["samples"]:
            for kind, value in (s.get("sensors") or {}).items():
                if kind in kinds:  # beside the field sensors of the same type
                    add(kind, drone_id, s["t_s"], value)
    return series
