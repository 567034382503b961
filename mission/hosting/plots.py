"""The plots of a simulation result (SPEC §5), drawn with matplotlib (Agg): paths,
altitude, battery, distances and, where links were measured, link quality."""

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
    return written
