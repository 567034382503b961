"""Which free drone serves which assignment request (thesis §5.2.4), as pure logic.

Requests come by id, by sensors, near a position, by kind, by role, or for any drone.
Several at once are served in the thesis's priority order — ids first, then sensor
requests (more sensors first), then kind and role, then proximity, then drones that
may relay, then any — so the constrained requests pick before the easy ones take their
drones. Among fitting drones: the closest for a proximity request; otherwise the one
with the fewest sensors (keep rare sensors free for whoever needs them), then one that
may not relay; ties go to the most battery. If any request cannot be met, none is: the
mission fails with cause `requirements`.

An `auxiliary` drone (SPEC §2 About roles; thesis §7.2 item 7) is kept for others:
never picked by any, sensors, kind or proximity — only by id, by role, as a relay
(preferred after the drones declaring `relay`) or as a replacement (preferred first).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from dronefleet.schemas.about import AUXILIARY, DEFAULT_ROLES, RELAY, ROLES
from dronefleet.schemas.errors import FleetError
from dronefleet.schemas.geo import distance_m


@dataclass(frozen=True)
class Candidate:
    """A free drone as the assigner sees it."""

    drone_id: str
    sensors: frozenset[str] = frozenset()
    battery: float = 0.0  # 0..1
    lat: float | None = None
    lon: float | None = None
    kind: str | None = None  # drone type (About `kind`; thesis §7.2 item 7), None until heard
    relay: bool = True  # may carry other drones' traffic (on a secured mesh: issued `--role relay`)
    roles: frozenset[str] = frozenset(DEFAULT_ROLES)  # About `roles` (the default until heard)

    @property
    def auxiliary(self) -> bool:
        return AUXILIARY in self.roles


@dataclass(frozen=True)
class ById:
    drone_id: str


@dataclass(frozen=True)
class BySensors:
    sensors: frozenset[str]


@dataclass(frozen=True)
class Near:
    lat: float
    lon: float


@dataclass(frozen=True)
class ByKind:
    kind: str


@dataclass(frozen=True)
class ByRole:
    role: str

    def __post_init__(self) -> None:  # assign(role=…) and with_role(…) alike
        if self.role not in ROLES:
            raise ValueError(f"assign: role {self.role!r} is not one of {', '.join(ROLES)}")


@dataclass(frozen=True)
class AnyDrone:
    pass


@dataclass(frozen=True)
class AnyRelay:
    """A drone that may relay for others: any drone, except on a secured mesh (SPEC §9),
    where only those issued `--role relay` carry their neighbours' traffic."""

    def __repr__(self) -> str:
        return "any_relay"


Part = ById | BySensors | Near | ByKind | ByRole | AnyRelay | AnyDrone


@dataclass(frozen=True)
class AllOf:
    """One drone meeting every part: `assign(sensor="gas", role="survey", near=pos)` —
    keyword arguments describe one drone (the nearest of those fitting, with `near`)."""

    parts: tuple[Part, ...]


Request = Part | AllOf


def parts_of(request: Request) -> tuple[Request, ...]:
    return request.parts if isinstance(request, AllOf) else (request,)


def sensors_of(request: Request) -> frozenset[str]:
    """The sensors a request asked for (the mission fails `sensor` should one go)."""
    return frozenset().union(*(p.sensors for p in parts_of(request) if isinstance(p, BySensors)))


class Unfulfilled(FleetError):
    """No free drone meets a request (mission cause `requirements`)."""

    def __init__(self, request: Request, reason: str) -> None:
        super().__init__(f"cannot assign {describe(request)}: {reason}")
        self.request = request


def describe(request: Request) -> str:
    match request:
        case ById(drone_id):
            return f"drone {drone_id!r}"
        case BySensors(sensors):
            return f"a drone with {', '.join(sorted(sensors))}"
        case ByKind(kind):
            return f"a drone of kind {kind!r} (auxiliary drones aside)"
        case ByRole(role):
            return f"a drone with the role {role!r}"
        case AnyRelay():
            return "a drone that may relay (on a secured mesh: issued --role relay and declaring the relay role)"
        case Near(lat, lon):
            return f"the drone nearest {lat:.6f}, {lon:.6f} (auxiliary drones aside)"
        case AllOf(parts):
            return " and ".join(describe(p) for p in parts)
    return "any drone (auxiliary drones aside)"


def replaceable(request: Request) -> bool:
    """Drones assigned by id or sensor are irreplaceable (another drone would lack what
    the mission asked for); those assigned near a place, by kind, role or as any are not."""
    return not any(isinstance(p, (ById, BySensors)) for p in parts_of(request))


def _rank(request: Request) -> tuple[int, int]:
    match request:
        case AllOf(parts):
            return min(_rank(p) for p in parts)
        case ById():
            return (0, 0)
        case BySensors(sensors):
            return (1, -len(sensors))
        case ByKind() | ByRole():
            return (2, 0)
        case Near():
            return (3, 0)
        case AnyRelay():
            return (4, 0)
    return (5, 0)


def _distance(c: Candidate, lat: float, lon: float) -> float:
    return distance_m(c.lat, c.lon, lat, lon) if c.lat is not None and c.lon is not None else float("inf")


def _fits(part: Request, c: Candidate) -> bool:
    """Whether a free drone meets one request, the auxiliary rule aside."""
    match part:
        case ById(drone_id):
            return c.drone_id == drone_id
        case BySensors(sensors):
            return sensors <= c.sensors
        case ByKind(kind):
            return c.kind == kind
        case ByRole(role):
            return role in c.roles
        case AnyRelay():
            return c.relay
        case AllOf(parts):
            return all(_fits(p, c) for p in parts)
    return True  # Near, AnyDrone


def _names_auxiliary(request: Request) -> bool:
    """Requests that may take an auxiliary drone: by id, by role, as a relay."""
    return any(isinstance(p, (ById, ByRole, AnyRelay)) for p in parts_of(request))


def relay_preference(c: Candidate) -> tuple[bool, bool]:
    """Which free drones `any_relay` takes first (lowest): those declared for it, then
    the auxiliary ones, then the others."""
    return (RELAY not in c.roles, not c.auxiliary)


def choose(request: Request, free: Sequence[Candidate]) -> Candidate:
    """The best free drone for one request, or Unfulfilled."""
    parts = parts_of(request)
    may_take_auxiliary = _names_auxiliary(request)
    fitting = [c for c in free if _fits(request, c) and (may_take_auxiliary or not c.auxiliary)]
    if not fitting:
        reason = "no free drone" if not free else "no free drone fits"
        if free and all(c.auxiliary for c in free) and not may_take_auxiliary:
            reason = f"only auxiliary drones are free ({', '.join(c.drone_id for c in free)}): name one, or assign(role='auxiliary')"
        if any(isinstance(p, ById) for p in parts):
            reason = "it is not registered, not ready, or in another mission"
        raise Unfulfilled(request, reason)
    place = next((p for p in parts if isinstance(p, Near)), None)
    if place is not None:
        located = [c for c in fitting if c.lat is not None]
        if not located:
            raise Unfulfilled(request, "no free drone reports a position")
        return min(located, key=lambda c: (_distance(c, place.lat, place.lon), -c.battery, c.drone_id))
    if any(isinstance(p, AnyRelay) for p in parts):  # those declared for it, then the auxiliary ones, then the others
        return min(fitting, key=lambda c: (*relay_preference(c), len(c.sensors), -c.battery, c.drone_id))
    # Keep rare sensors, and the right to relay, free for whoever needs them.
    return min(fitting, key=lambda c: (len(c.sensors), c.relay, -c.battery, c.drone_id))


def assign_many(requests: Sequence[Request], free: Sequence[Candidate]) -> list[str]:
    """Drone ids for `requests`, in the order asked, all or nothing."""
    chosen: dict[int, str] = {}
    pool = list(free)
    for index in sorted(range(len(requests)), key=lambda i: (_rank(requests[i]), i)):
        pick = choose(requests[index], pool)
        chosen[index] = pick.drone_id
        pool = [c for c in pool if c.drone_id != pick.drone_id]
    return [chosen[i] for i in range(len(requests))]


def replacement(lat: float, lon: float, free: Sequence[Candidate]) -> str | None:
    """The free drone closest to where the replaced one stopped (thesis §5.2.4): a free
    auxiliary drone first (thesis §7.2 item 7), else any other."""
    located = [c for c in free if c.lat is not None and c.lon is not None]
    if not located:
        return None
    return min(located, key=lambda c: (not c.auxiliary, _distance(c, lat, lon), -c.battery, c.drone_id)).drone_id
