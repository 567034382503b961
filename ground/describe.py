"""How the ground words status events: the thesis-style log lines and descriptions.

"Start takeoff with altitude 10.0m", "Queued go to 40.634421, -8.660437 at 15.0m",
"Finish takeoff", "Cancel land", "Success on arm", "Failure on takeoff: disarmed",
"Auto disarmed" (thesis examples 24, 29, 30). A command's target (goto coordinates)
names it in every later line; an altitude only in its start line, as the thesis does.
"""

from __future__ import annotations

from typing import Literal

import msgspec

from dronefleet.schemas.bundles import BundleStatus, Step
from dronefleet.schemas.status import CommandStatus, SystemStatus

Level = Literal["info", "warn", "error"]

# Commands whose wire name reads badly in a sentence.
_NAMES = {"goto": "go to", "move": "move to", "return": "return to launch"}


class Described(msgspec.Struct, frozen=True):
    name: str  # "go to 40.634421, -8.660437 at 15.0m", "takeoff"
    current: str  # the registry's current_command description


def _metres(value: float) -> str:
    return f"{round(value, 2)}m"


def _verb(command: str) -> str:
    return _NAMES.get(command, command.replace("_", " "))


def _at(lat: float, lon: float, alt: float | None) -> str:
    return f"{lat:.6f}, {lon:.6f}" + (f" at {_metres(alt)}" if alt is not None else "")


def _capital(text: str) -> str:
    return text[0].upper() + text[1:]


def describe_start(status: CommandStatus) -> Described:
    if status.coords is not None:
        c = status.coords
        name = f"{_verb(status.command)} {_at(c.lat, c.lon, c.alt)}"
        return Described(name, _capital(name))
    # No target known (a status whose start was not heard): "Finish move", not "… move to".
    name = _verb(status.command) if status.command not in ("goto", "move") else status.command
    current = _capital(name)
    if status.altitude is not None:
        current = f"{current} with altitude {_metres(status.altitude)}"
    return Described(name, current)


def status_line(status: CommandStatus, described: Described) -> tuple[Level, str]:
    reason = f": {status.reason}" if status.reason else ""
    if status.state == "start":
        return "info", f"Start {described.current[0].lower()}{described.current[1:]}"
    if status.state == "failure":
        return "warn", f"Failure on {described.name}{reason}"
    if status.state == "success":
        return "info", f"Success on {described.name}"
    return "info", f"{status.state.capitalize()} {described.name}{reason}"


_SYSTEM: dict[str, tuple[Level, str]] = {
    "connect": ("info", "Flight controller system connected"),
    "disconnect": ("warn", "Flight controller system disconnected"),
    "disarm": ("info", "Auto disarmed"),
    "return": ("warn", "Automatic return to launch"),
    "stop_offboard": ("warn", "Offboard mode stopped by the flight controller"),
    "start_manual": ("info", "Start manual mode"),
    "stop_manual": ("info", "Stop manual mode"),
    "link_lost": ("warn", "Lost link to ground station"),
    "link_restored": ("info", "Link to ground station restored"),
    "failsafe": ("warn", "Failsafe action by the agent"),
}


def system_line(status: SystemStatus) -> tuple[Level, str]:
    level, message = _SYSTEM.get(status.state, ("info", f"System event {status.state}"))
    return level, f"{message}: {status.reason}" if status.reason else message


def describe_step(step: Step) -> str:
    """A bundle step as a person reads it: "Go to 40.633700, -8.660500 at 10.0m", "Wait 5 s"."""
    if step.command is None:
        text = f"Wait {step.wait_s:g} s"
    else:
        cmd = step.command
        name = _verb(cmd.name)
        lat, lon, alt = (getattr(cmd, f, None) for f in ("lat", "lon", "alt"))
        if lat is not None and lon is not None:
            text = f"{name} {_at(lat, lon, alt)}"
        elif alt is not None:
            text = f"{name} with altitude {_metres(alt)}"
        elif cmd.name == "move":
            parts = [f"{abs(v):g} m {pos if v > 0 else neg}" for v, pos, neg in (
                (getattr(cmd, "y", 0), "forward", "backward"), (getattr(cmd, "x", 0), "right", "left"),
                (getattr(cmd, "z", 0), "up", "down")) if v]
            text = "move " + (", ".join(parts) or "nowhere")
        else:
            text = name
        text = _capital(text)
    return f"{text} until {step.until}" if step.until is not None else text


def bundle_line(status: BundleStatus, description: str | None) -> tuple[Level, str] | None:
    """The thesis-style line for a bundle event (None: the step's command says it)."""
    b, n = f"Bundle {status.bundle_id}", status.steps or 0
    at = f"step {status.step + 1}/{n}" if n else f"step {status.step + 1}"
    why = f": {status.reason}" if status.reason else ""
    match status.state:
        case "start":
            return "info", f"{b} {at}: {description or status.command or 'step'}"
        case "finish":
            return None
        case "guard" if status.scope == "bundle":
            return "info", f"{b} ended by {status.reason} at step {status.step + 1}"
        case "guard":
            return "info", f"{b} {at} ended by {status.reason}"
        case "done":
            return "info", f"{b} done ({n} steps)"
        case "failure":
            return "warn", f"{b} failed at {at}{why}"
        case _:
            return "warn", f"{b} cancelled at {at}{why}"
