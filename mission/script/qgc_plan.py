"""QGroundControl plans into mission scripts (SPEC §13), as pure functions.

A plan is JSON (`fileType: Plan`, mission `version` 2). Its simple items become verbs:
MAV_CMD 22 takeoff, 16 waypoint (param1: hold s), 19 loiter time (param1: s), 20 return
to launch, 21 land, 178 change speed (param2: m/s), 93 and 112 delays (param1: s);
frames 3 (altitude relative to home) and 0 (AMSL), and 2 for the items without a
position. Anything else — other commands, other frames, terrain-relative altitudes
without terrain data, complex items such as surveys — is named with its item number
(1-based, as QGroundControl numbers them) and left out, never silently. The plan's
inclusion polygon becomes the ground's `geofence:`; circles, exclusion polygons, more
polygons and rally points are named as not applied.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from dronefleet.schemas.errors import FleetError

TAKEOFF, WAYPOINT, LOITER_TIME, RETURN, LAND, CHANGE_SPEED, NAV_DELAY, CONDITION_DELAY = 22, 16, 19, 20, 21, 178, 93, 112
FRAME_AMSL, FRAME_MISSION, FRAME_RELATIVE = 0, 2, 3
NAMES = {TAKEOFF: "takeoff", WAYPOINT: "waypoint", LOITER_TIME: "loiter time", RETURN: "return to launch",
         LAND: "land", CHANGE_SPEED: "change speed", NAV_DELAY: "delay", CONDITION_DELAY: "delay"}
FRAMES = {FRAME_AMSL: "AMSL", FRAME_MISSION: "none", FRAME_RELATIVE: "relative to home", 10: "terrain"}


class NotAPlan(FleetError):
    """The file is not a QGroundControl plan this importer reads (exit 2)."""

    exit_code = 2


@dataclass
class Imported:
    """A plan as a mission script: its text, the geofence to give the ground (None when
    the plan has no inclusion polygon), and what was left out, one line per item."""

    script: str
    geofence: dict[str, Any] | None
    left_out: list[str] = field(default_factory=list)
    # The same plan as the dashboard's planner edits it: waypoints {lat, lon, alt (m above
    # home), hold_s, speed}, the takeoff altitude and how it ends (land, return or hold).
    waypoints: list[dict[str, Any]] = field(default_factory=list)
    takeoff_alt: float | None = None
    end: str = "hold"


def read_plan(text: str) -> dict[str, Any]:
    try:
        plan = json.loads(text)
    except json.JSONDecodeError as exc:
        raise NotAPlan(f"not a QGroundControl plan: not JSON ({exc})") from None
    if not isinstance(plan, dict) or plan.get("fileType") != "Plan":
        raise NotAPlan("not a QGroundControl plan: no \"fileType\": \"Plan\"")
    mission = plan.get("mission")
    if not isinstance(mission, dict) or not isinstance(mission.get("items"), list):
        raise NotAPlan("not a QGroundControl plan: no mission items")
    if mission.get("version") != 2:
        raise NotAPlan(f"mission version {mission.get('version')!r}: only version 2 plans are read")
    return plan


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) else None


def _coords(params: list[Any]) -> tuple[float, float] | None:
    lat, lon = _number(params[4]), _number(params[5])
    return (lat, lon) if lat is not None and lon is not None and (lat, lon) != (0.0, 0.0) else None


class _Script:
    """The verbs of one plan, line by line, and what was left out."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.left_out: list[str] = []
        self.took_off = False
        self.speed = False  # a change-speed item came: moves pass `speed`
        self.home_alt: float | None = None  # plannedHomePosition's, for frame-0 altitudes
        self.waypoints: list[dict[str, Any]] = []
        self.speed_now: float | None = None
        self.takeoff_alt: float | None = None
        self.end = "hold"

    def skip(self, number: int, why: str) -> None:
        self.left_out.append(f"item {number}: {why}")

    def goto(self, number: int, what: str, frame: int, params: list[Any]) -> bool:
        where = _coords(params)
        metres = _number(params[6])
        if where is None:
            self.skip(number, f"{what} without a position")
            return False
        if metres is None:
            self.skip(number, f"{what} without an altitude (terrain-relative altitudes need terrain data)")
            return False
        self.move(number, where, f"launch.alt + {metres:g}*m" if frame == FRAME_RELATIVE else f"{metres:g}*m")
        relative = metres if frame == FRAME_RELATIVE else round(metres - self.home_alt, 3) if self.home_alt is not None else None
        if relative is not None:
            self.waypoints.append({"lat": where[0], "lon": where[1], "alt": relative, "hold_s": 0.0, "speed": self.speed_now})
        return True

    def move(self, number: int, where: tuple[float, float], alt: str | None) -> None:
        """A `move` to a position, at `alt` (the script's expression) or the altitude it has."""
        extra = (f", alt={alt}" if alt is not None else "") + (", speed=speed" if self.speed else "")
        self.lines.append(f"move(d, lat={where[0]!r}, lon={where[1]!r}{extra})  # item {number}")

    def take_off_first(self, number: int) -> None:
        if not self.took_off:
            self.lines += ["arm(d)", "takeoff(d)  # the agent's takeoff altitude"]
            self.skip(number, "the plan does not start with a takeoff; the script takes off first")
            self.took_off = True

    def item(self, number: int, command: int, frame: int, params: list[Any]) -> None:
        name = NAMES[command]
        if command in (TAKEOFF, WAYPOINT, LOITER_TIME, LAND) and frame not in (FRAME_AMSL, FRAME_RELATIVE):
            self.skip(number, f"{name} in frame {FRAMES.get(frame, frame)} (only 3, relative to home, or 0, AMSL)")
        elif command == TAKEOFF:
            metres = _number(params[6])
            if metres is None:
                self.skip(number, "takeoff without an altitude")
                return
            if not self.took_off:
                self.lines.append("arm(d)")
                self.took_off = True
            alt = f"{metres:g}*m" if frame == FRAME_RELATIVE else f"{metres:g}*m - launch.alt"
            self.lines.append(f"takeoff(d, {alt})  # item {number}")
            if frame == FRAME_RELATIVE or self.home_alt is not None:
                self.takeoff_alt = metres if frame == FRAME_RELATIVE else metres - (self.home_alt or 0.0)
        elif command == CHANGE_SPEED:
            metres_s = _number(params[1])
            if metres_s is None or metres_s <= 0:
                self.skip(number, "change speed without a speed (param 2)")
                return
            self.lines.append(f"speed = {metres_s:g}*m/s  # item {number}")
            self.speed = True
            self.speed_now = metres_s
        elif command in (NAV_DELAY, CONDITION_DELAY):
            seconds = _number(params[0])
            if seconds is None or seconds < 0:
                self.skip(number, "a delay until a time of day (param 1 of -1) is not carried over")
                return
            self.lines.append(f"sleep({seconds:g}*s)  # item {number}")
        else:
            self.take_off_first(number)
            if command == RETURN:
                self.lines.append(f"home(d)  # item {number}")
                self.end = "return"
            elif command == LAND:
                self.end = "land"
                where = _coords(params)
                if where is not None:  # PX4 flies there at the altitude it has, then lands
                    self.move(number, where, None)
                self.lines.append(f"land(d)  # item {number}")
            elif self.goto(number, name, frame, params):
                hold = _number(params[0]) or 0.0
                if self.waypoints and hold > 0:
                    self.waypoints[-1]["hold_s"] = hold
                if hold > 0:
                    self.lines.append(f"sleep({hold:g}*s)  # item {number}: {'hold' if command == WAYPOINT else 'loiter'}")


def import_plan(text: str, drone_id: str | None = None, source: str = "plan") -> Imported:
    """The script for one drone (`drone_id`, or any free drone) flying the plan."""
    plan = read_plan(text)
    script = _Script()
    home = plan["mission"].get("plannedHomePosition")
    if isinstance(home, list) and len(home) == 3:
        script.home_alt = _number(home[2])
    items = plan["mission"]["items"]
    for number, item in enumerate(items, start=1):
        if not isinstance(item, dict):
            script.skip(number, "not an item object")
        elif item.get("type") != "SimpleItem":
            kind = item.get("complexItemType", item.get("type"))
            script.skip(number, f"complex item {kind!r} (a survey, corridor or structure scan) is not carried over")
        elif not (isinstance(item.get("command"), int) and isinstance(item.get("frame"), int)
                  and isinstance(item.get("params"), list) and len(item["params"]) == 7):
            script.skip(number, "malformed (a command, a frame and seven params expected)")
        elif item["command"] not in NAMES:
            script.skip(number, f"MAV_CMD {item['command']} is not carried over")
        else:
            script.item(number, item["command"], item["frame"], item["params"])
    fence, notes = _fence(plan)
    header = [f'"""Imported from {source} by `fleet mission import` (a QGroundControl plan of {len(items)} items)."""',
              f"d = assign({drone_id!r})" if drone_id else "d = assign()",
              "launch = d.home  # where frame-3 altitudes count from (`home` is the return verb)"]
    body = script.lines or ["pass  # nothing of the plan could be carried over"]
    return Imported(script="\n".join(header + body) + "\n", geofence=fence, left_out=script.left_out + notes,
                    waypoints=script.waypoints, takeoff_alt=script.takeoff_alt, end=script.end)


def _section(plan: dict[str, Any], name: str, key: str) -> list[Any]:
    section = plan.get(name)
    entries = section.get(key) if isinstance(section, dict) else None
    return entries if isinstance(entries, list) else []


def _vertices(polygon: dict[str, Any]) -> list[list[float]] | None:
    vertices = polygon.get("polygon")
    if not isinstance(vertices, list) or len(vertices) < 3:
        return None
    out = []
    for vertex in vertices:
        lat, lon = (_number(vertex[0]), _number(vertex[1])) if isinstance(vertex, list) and len(vertex) == 2 else (None, None)
        if lat is None or lon is None:
            return None
        out.append([lat, lon])
    return out


def _fence(plan: dict[str, Any]) -> tuple[dict[str, Any] | None, list[str]]:
    notes: list[str] = []
    chosen: dict[str, Any] | None = None
    for i, polygon in enumerate(_section(plan, "geoFence", "polygons"), start=1):
        vertices = _vertices(polygon) if isinstance(polygon, dict) else None
        if isinstance(polygon, dict) and polygon.get("inclusion", True) is False:
            notes.append(f"geofence polygon {i}: an exclusion polygon is not applied (the ground's fence is one inclusion polygon)")
        elif vertices is None:
            notes.append(f"geofence polygon {i}: not applied (not 3 or more [lat, lon] vertices)")
        elif chosen is None:
            chosen = {"polygon": vertices}
        else:
            notes.append(f"geofence polygon {i}: not applied (the ground's fence is one inclusion polygon)")
    for i, _ in enumerate(_section(plan, "geoFence", "circles"), start=1):
        notes.append(f"geofence circle {i}: not applied (the ground's fence is a polygon)")
    for i, _ in enumerate(_section(plan, "rallyPoints", "points"), start=1):
        notes.append(f"rally point {i}: not applied (returns go home)")
    return chosen, notes


# ---- waypoints out to a plan (the dashboard's export, SPEC §13) ---------------------------

ENDS = ("land", "return", "hold")


@dataclass(frozen=True)
class Waypoint:
    lat: float
    lon: float
    alt: float  # m above home
    hold_s: float = 0.0
    speed: float | None = None  # m/s on the way to it (None: the vehicle's own)


def export_plan(waypoints: list[Waypoint], home: tuple[float, float, float], takeoff_alt: float, end: str = "land",
                fence: list[list[float]] | None = None) -> dict[str, Any]:
    """A waypoint plan as QGroundControl writes one (a plan of its own opened and saved
    again has the same shape: `fileType` Plan, mission `version` 2, `SimpleItem`s in
    frame 3 with `Altitude`/`AltitudeMode`/`AMSLAltAboveTerrain` where they have a
    position, `plannedHomePosition` [lat, lon, AMSL]): takeoff from `home` to
    `takeoff_alt`, a change-speed item where a waypoint's speed differs from the last,
    each waypoint with its hold time, then land where the last one is, return, or hold
    there. `fence`: an inclusion polygon of [lat, lon]. `import_plan` reads it back to
    the same waypoints."""
    if end not in ENDS:
        raise ValueError(f"end must be one of {', '.join(ENDS)}, got {end!r}")
    if not waypoints:
        raise ValueError("a plan needs at least one waypoint")
    items: list[dict[str, Any]] = []

    def add(command: int, frame: int, params: list[Any], alt: float | None = None) -> None:
        item: dict[str, Any] = {"autoContinue": True, "command": command, "doJumpId": len(items) + 1, "frame": frame,
                                "params": params, "type": "SimpleItem"}
        if alt is not None:
            item.update({"AMSLAltAboveTerrain": None, "Altitude": alt, "AltitudeMode": 1})
        items.append(item)

    add(TAKEOFF, FRAME_RELATIVE, [0, 0, 0, None, home[0], home[1], takeoff_alt], takeoff_alt)
    speed: float | None = None
    for w in waypoints:
        if w.speed is not None and w.speed != speed:
            add(CHANGE_SPEED, FRAME_MISSION, [1, w.speed, -1, 0, 0, 0, 0])
            speed = w.speed
        add(WAYPOINT, FRAME_RELATIVE, [w.hold_s, 0, 0, None, w.lat, w.lon, w.alt], w.alt)
    last = waypoints[-1]
    if end == "land":
        add(LAND, FRAME_RELATIVE, [0, 0, 0, None, last.lat, last.lon, 0], 0)
    elif end == "return":
        add(RETURN, FRAME_MISSION, [0, 0, 0, 0, 0, 0, 0])
    return {
        "fileType": "Plan", "version": 1, "groundStation": "Fleet",
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "globalPlanAltitudeMode": 1,
                    "cruiseSpeed": 15, "hoverSpeed": speed or 5, "plannedHomePosition": list(home), "items": items},
        "geoFence": {"version": 2, "circles": [],
                     "polygons": [{"inclusion": True, "polygon": fence, "version": 1}] if fence else []},
        "rallyPoints": {"version": 2, "points": []},
    }
