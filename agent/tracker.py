"""Status tracking as pure functions of flight-controller snapshots.

MAVSDK (like any MAVLink autopilot) only acknowledges that a command was taken, so
completion is decided by watching telemetry (thesis §4.1.4): `finished` says when a
running command reached its goal, `interrupted` when the autopilot went elsewhere
on its own (a pilot, a failsafe), and `system_events` which unrequested events
happened between two snapshots. Mode changes are judged on transitions, so a
snapshot that still lags behind a command (up to one heartbeat) is never mistaken
for an event.
"""

from __future__ import annotations

from dataclasses import dataclass

from dronefleet.agent.fc_port import FcState
from dronefleet.agent.priority import SETPOINTS
from dronefleet.schemas.geo import angle_diff_deg, distance_m
from dronefleet.schemas.telemetry import MANUAL_MODES

HEADING_TOLERANCE_DEG = 2.0


@dataclass(frozen=True)
class Goal:
    """What done means for one command; only the fields its kind needs are set."""

    kind: str  # altitude | position | landed | heading | local | none
    rel_alt: float = 0.0
    lat: float = 0.0
    lon: float = 0.0
    alt: float = 0.0
    heading: float = 0.0
    ned: tuple[float, float, float] = (0.0, 0.0, 0.0)


def finished(goal: Goal, s: FcState, radius_m: float) -> bool:
    if goal.kind == "landed":
        return s.landed_state == "on_ground"
    if goal.kind == "altitude":
        return (
            s.position is not None
            and s.landed_state == "in_air"
            and s.flight_mode != "takeoff"
            and s.position.rel_alt >= goal.rel_alt - max(radius_m, 0.15 * goal.rel_alt)
        )
    if goal.kind == "position":
        return (
            s.position is not None
            and distance_m(s.position.lat, s.position.lon, goal.lat, goal.lon) <= radius_m
            and abs(s.position.alt - goal.alt) <= max(radius_m, 0.5)
        )
    if goal.kind == "heading":
        return abs(angle_diff_deg(s.heading, goal.heading)) <= HEADING_TOLERANCE_DEG
    if goal.kind == "local":
        if s.local_ned is None:
            return False
        dn, de, dd = (a - b for a, b in zip(s.local_ned, goal.ned, strict=True))
        return (dn * dn + de * de) ** 0.5 <= radius_m and abs(dd) <= max(radius_m, 0.5)
    return False


def interrupted(command: str, prev: FcState, now: FcState) -> str | None:
    """Why the autopilot's mode left `command` between two snapshots, if it did. (A
    disarm is judged on the handler's one view of arming, agent/arming.py.)"""
    if now.flight_mode == prev.flight_mode:
        return None
    if now.flight_mode in MANUAL_MODES:
        return "manual control"
    if now.flight_mode == "return_to_launch" and command != "return":
        return "automatic return"
    if now.flight_mode == "land" and command not in ("land", "return"):
        return "automatic landing"
    if prev.flight_mode == "offboard" and command in SETPOINTS:
        return "offboard stopped"
    return None


def system_events(prev: FcState, now: FcState, recent: frozenset[str], disarmed_alone: bool = False) -> list[str]:
    """Unrequested events between two snapshots. `recent` names the commands the
    agent itself accepted within the last few seconds (their effects are not events);
    `disarmed_alone`: the arming view saw an unrequested disarm edge (agent/arming.py)."""
    events: list[str] = []
    if now.connected != prev.connected:
        events.append("connect" if now.connected else "disconnect")
    if not now.connected:
        return events
    if disarmed_alone:
        events.append("disarm")
    mode_changed = now.flight_mode != prev.flight_mode
    if mode_changed and now.flight_mode == "return_to_launch" and "return" not in recent:
        events.append("return")
    if (
        mode_changed and prev.flight_mode == "offboard"
        and now.flight_mode not in MANUAL_MODES
        and not (recent - SETPOINTS - {"arm"})
    ):
        events.append("stop_offboard")
    if mode_changed and now.flight_mode in MANUAL_MODES and prev.flight_mode not in MANUAL_MODES:
        events.append("start_manual")
    if mode_changed and prev.flight_mode in MANUAL_MODES and now.flight_mode not in MANUAL_MODES:
        events.append("stop_manual")
    return events
