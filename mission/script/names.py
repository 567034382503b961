"""The names of a mission script's world besides the verbs' functions: the verbs' list,
and what every script (and every plugin, at load and when enabled) sees: builtins,
units, geo, directions, assignment helpers."""

from __future__ import annotations

import math
from typing import Any

from dronefleet.mission.lifecycle import assignment as a
from dronefleet.mission.script import position as geo
from dronefleet.mission.script import units
from dronefleet.mission.script.drone import any_drone
from dronefleet.mission.script.position import as_position
from dronefleet.mission.script.relaying import Relays
from dronefleet.mission.script.sandbox import Guards

# The DSL's verbs (SPEC §5): the one list. build_namespace binds each name to the
# function of that name it defines, so a verb cannot be listed without existing.
VERBS = (
    "assign", "revoke", "replace", "arm", "disarm", "takeoff", "land", "home", "cancel", "turn",
    "move", "push", "sleep", "run", "wait", "stop", "enable", "disable", "field_sensors",
)
VERB_NAMES = (*VERBS, "channel", "mission_id", "step", "when")  # every name a mission script gets from its mission


def common_names(guards: Guards) -> dict[str, Any]:
    """What every script sees besides the verbs: builtins, units, geo, directions."""
    namespace: dict[str, Any] = {
        "__builtins__": guards.builtins(),
        "__name__": "mission",
        **guards.hooks(),
        "any_drone": any_drone,
        "any_relay": a.AnyRelay(),
        "with_sensors": lambda *kinds: a.BySensors(frozenset(kinds)),
        "near": near_place,
        "of_kind": a.ByKind,
        "with_role": a.ByRole,
        "position": geo.position,
        "distance": geo.distance,
        "bearing": geo.bearing,
        "target": geo.target,
        "north": 0 * units.deg,
        "east": 90 * units.deg,
        "south": 180 * units.deg,
        "west": 270 * units.deg,
        "pi": math.pi,
        "relays": Relays(),
    }
    namespace.update(units.UNITS)
    return namespace


def near_place(place: Any) -> a.Near:
    """`assign(near(coords))`: the free drone closest to a place."""
    p = as_position(place)
    return a.Near(p.lat, p.lon)
