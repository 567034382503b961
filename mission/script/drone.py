"""The drone as a mission script sees it (SPEC §5): its live state read from the
ground's registry, positions relative to it, and where the next relative move is
planned from; `any_drone`; and how a verb runs a mission coroutine (`call`) and
unwinds its caller when the mission ends (`guarded`)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from greenlet import getcurrent

from dronefleet.mission.lifecycle.greenlets import Stopped, await_
from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.lifecycle.record import MissionOver
from dronefleet.mission.script.lines import script_line
from dronefleet.mission.script.position import Position
from dronefleet.schemas.about import DEFAULT_ROLES
from dronefleet.schemas.telemetry import LinkQuality

COMPLETED = frozenset({"success", "finish"})
MIN_HANDOVER_HEIGHT_M = 2.0
# An idle drone this close to its last target (by telemetry up to a period old, at
# cruise speed) plans from that target.
ANCHOR_RADIUS_M = 10.0


class _AnyDrone:
    __slots__ = ()

    def __repr__(self) -> str:
        return "any_drone"


any_drone = _AnyDrone()


def guarded(fn: Callable[..., Any]) -> Callable[..., Any]:
    """A verb as scripts see it: a mission that ends unwinds the caller (uncatchably)."""

    def verb(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except MissionOver:
            raise Stopped() from None

    verb.__name__ = fn.__name__
    verb.__doc__ = fn.__doc__
    return verb


def call(mission: Mission, awaitable: Any) -> Any:
    """Run a mission coroutine from a script; a mission that ends unwinds the caller."""
    try:
        return await_(awaitable)
    except MissionOver:
        raise Stopped() from None


def unknowable(mission: Mission, what: str) -> None:
    """The script read `what`, whose value a prediction cannot know (a sensor's reading,
    the field sensors heard, the radio): its host hears of it with the script's line."""
    if mission.on_unknowable is not None:
        mission.on_unknowable(mission, script_line(mission), what)


class CommandView:
    """`drone.cmd`: the drone's current command, with `.target` for takeoff/goto/move."""

    __slots__ = ("description", "name", "target")

    def __init__(self, name: str, description: str, target: Position | float | None) -> None:
        self.name = name
        self.description = description
        self.target = target

    def as_position(self) -> Position:
        if not isinstance(self.target, Position):
            raise ValueError(f"the current command ({self.description}) has no target position")
        return self.target

    def distance(self, other: Any) -> float:
        return self.as_position().distance(other)

    def bearing(self, other: Any) -> float:
        return self.as_position().bearing(other)

    def __repr__(self) -> str:
        return f"<cmd {self.description}>"


class Fields:
    """A reading declared with fields: each field by name, as an attribute
    (`drone.sensor.gas.co_ppm`) or an item (`drone.sensor.gas["pm2.5"]`, for names that
    cannot be attributes; the wire carries a JSON object). One the reading did not carry
    is None, one the sensor does not declare an error."""

    __slots__ = ("_declared", "_kind", "_values")

    def __init__(self, kind: str, values: dict[str, Any], declared: frozenset[str]) -> None:
        self._kind = kind
        self._values = values
        self._declared = declared

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        if name in self._values:
            return self._values[name]
        if self._declared and name not in self._declared:
            raise AttributeError(f"the {self._kind} sensor has no field {name!r} (declared: {', '.join(sorted(self._declared))})")
        return None

    def __getitem__(self, name: str) -> Any:
        if name in self._values:
            return self._values[name]
        if self._declared and name not in self._declared:
            raise KeyError(f"the {self._kind} sensor has no field {name!r} (declared: {', '.join(sorted(self._declared))})")
        return None

    def __repr__(self) -> str:
        return f"<{self._kind} {', '.join(f'{k}={v!r}' for k, v in sorted(self._values.items()))}>"


def reading_value(reading: Any, declared: frozenset[str] = frozenset()) -> Any:
    """What a mission reads of one reading: its value, or its fields as attributes."""
    if reading.fields:
        return Fields(reading.type, dict(reading.fields), declared)
    return reading.value


class NoSuchSensor(AttributeError):
    """A script read a sensor its drone does not carry (`hasattr(d.sensor, "gas")` is False)."""


class SensorView:
    """`drone.sensor.temperature`: the latest reading of that type (a number, or for a
    sensor declared with fields an object of them: `drone.sensor.gas.co_ppm`), None
    before the first; NoSuchSensor when the drone carries no such sensor."""

    __slots__ = ("_drone",)

    def __init__(self, drone: Drone) -> None:
        self._drone = drone

    def __getattr__(self, kind: str) -> Any:
        if kind.startswith("_"):
            raise AttributeError(kind)
        registry, drone_id = self._drone._m.station.registry, self._drone._live()
        declared = next((d for d in registry.info(drone_id).sensors_declared or [] if d.type == kind), None)
        carried = registry.info(drone_id).sensors
        if kind not in carried and declared is None:
            raise NoSuchSensor(f"{drone_id} carries no {kind} sensor (it carries: {', '.join(carried) or 'none'}); "
                               f"assign(sensor={kind!r}) picks a drone that does")
        unknowable(self._drone._m, f"{drone_id}'s {kind} sensor")
        for reading in registry.sensor_readings(drone_id):
            if reading.type == kind:
                return reading_value(reading, frozenset(declared.fields) if declared else frozenset())
        return None


class Handle:
    """What the verbs keep of a drone wrapper, out of the script's sight: which drone it
    is now (a `replace` changes it), where its last verb left it (`anchor`), how many
    replacements it has seen (`generation`: a verb that spans one redoes its command),
    and a replacement handing it over (`handover`, set meanwhile)."""

    __slots__ = ("anchor", "drone_id", "generation", "handover", "handover_owner", "mission")

    def __init__(self, mission: Mission, drone_id: str) -> None:
        self.mission = mission
        self.drone_id = drone_id
        self.anchor: Position | None = None
        self.generation = 0
        self.handover: asyncio.Future[None] | None = None
        self.handover_owner: Any = None

    def live(self) -> str:
        """The drone behind the wrapper now; waits while a replacement is handing over."""
        handover = self.handover
        if handover is not None and getcurrent() is not self.handover_owner:
            call(self.mission, asyncio.shield(handover))
        try:
            self.mission.check_assigned(self.drone_id)
        except MissionOver:
            raise Stopped() from None
        return self.drone_id

    def telemetry(self) -> Any:
        return self.mission.station.registry.telemetry(self.live())

    def position(self) -> Position:
        t = self.telemetry()
        if t.position is None:
            raise ValueError(f"{self.drone_id} reports no position")
        return Position(t.position.lat, t.position.lon, t.position.alt, t.heading)

    def plan_base(self) -> Position:
        """Where the next relative move or turn starts.

        While the drone idles where its last verb left it, that verb's target (and
        heading) — exact, unlike telemetry up to one period old. Otherwise the next
        fresh telemetry sample, so a heading caught mid-turn is never used.
        """
        anchored = self.anchored()
        if anchored is not None:
            return anchored
        call(self.mission, self.mission.next_telemetry(self.live()))
        return self.position()

    def anchored(self) -> Position | None:
        """The last verb's target, if the drone idles there."""
        anchor = self.anchor
        if anchor is not None and self.mission.station.registry.info(self.live()).current_command is None:
            here = self.position()
            if here.distance(anchor) <= ANCHOR_RADIUS_M:
                alt = anchor.alt if anchor.alt is not None else here.alt
                return Position(anchor.lat, anchor.lon, alt, anchor.heading)
        return None


class Drone:
    """The drone wrapper (thesis table 5.4). It keeps its identity across `replace`."""

    __slots__ = ("_handle", "sensor")

    def __init__(self, mission: Mission, drone_id: str) -> None:
        self._handle = Handle(mission, drone_id)
        self.sensor = SensorView(self)

    def _live(self) -> str:
        return self._handle.live()

    def _telem(self) -> Any:
        return self._handle.telemetry()

    @property
    def _m(self) -> Mission:
        return self._handle.mission

    def __repr__(self) -> str:
        return f"<drone {self._handle.drone_id}>"

    @property
    def id(self) -> str:
        return self._handle.drone_id

    @property
    def state(self) -> str:
        return self._m.station.registry.info(self._live()).state

    @property
    def armed(self) -> bool:
        return bool(self._telem().armed)

    @property
    def battery(self) -> float:
        t = self._telem()
        return t.battery.remaining_percent if t.battery else 0.0

    @property
    def heading(self) -> float:
        return float(self._telem().heading)

    @property
    def speed(self) -> float:
        return float(self._telem().speed)

    @property
    def position(self) -> Position:
        return self._handle.position()

    @property
    def rel_alt(self) -> float:
        t = self._telem()
        return t.position.rel_alt if t.position else 0.0

    @property
    def home(self) -> Position | None:
        h = self._telem().home
        return Position(h.lat, h.lon, h.alt) if h else None

    @property
    def cmd(self) -> CommandView | None:
        current = self._m.station.registry.info(self._live()).current_command
        if current is None:
            return None
        c = current.command
        target: Position | float | None = None
        if current.coords is not None:
            target = Position(current.coords.lat, current.coords.lon, current.coords.alt)
        elif c in ("takeoff", "return") and current.altitude is not None:
            target = current.altitude
        return CommandView(c, current.description, target)

    @property
    def kind(self) -> str | None:
        """What the drone says it is (its agent's `kind`), None if it never said."""
        return self._m.station.registry.info(self._live()).kind

    @property
    def roles(self) -> tuple[str, ...]:
        """Its declared roles (survey, relay, auxiliary); the default ("survey",) if it never said."""
        roles = self._m.station.registry.info(self._live()).roles
        return tuple(roles) if roles is not None else DEFAULT_ROLES

    @property
    def link(self) -> LinkQuality | None:
        """The drone's measured link to the ground (`.quality`, `.rtt_ms`, `.jitter_ms`,
        `.loss`), or None before its first probe report."""
        drone_id = self._live()
        unknowable(self._m, f"{drone_id}'s link to the ground")
        return self._m.station.registry.info(drone_id).link

    def as_position(self) -> Position:
        return self.position

    # geo shortcuts on the drone itself
    def distance(self, other: Any) -> float:
        return self.position.distance(other)

    def bearing(self, other: Any) -> float:
        return self.position.bearing(other)

    def target(self, dist: Any, bearing: Any) -> Position:
        return self.position.target(dist, bearing)

    def forward(self, d: Any) -> Position:
        return self._plan_base().forward(d)

    def backward(self, d: Any) -> Position:
        return self._plan_base().backward(d)

    def left(self, d: Any) -> Position:
        return self._plan_base().left(d)

    def right(self, d: Any) -> Position:
        return self._plan_base().right(d)

    def up(self, d: Any) -> Position:
        return self._plan_base().up(d)

    def down(self, d: Any) -> Position:
        return self._plan_base().down(d)

    def _plan_base(self) -> Position:
        return self._handle.plan_base()


def handle(d: Drone) -> Handle:
    """The verbs' side of a drone wrapper."""
    return d._handle
