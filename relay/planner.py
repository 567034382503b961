"""Where relay drones go (SPEC §8 "Relay", issue 15): pure code, no I/O and no clock.

Everything is in a local frame in metres (north, east) around the ground station, which
is at (0, 0). One call of `plan` takes what the mission knows now — its drones'
positions, motion and the measured link qualities, the relays on duty — and returns
what to do: the relay points the fleet needs, which relay flies to which point (only
when its target moves by more than `step`), how many new relays to dispatch and which
relays to send home.

Measured mode (the default) decides on **measured** quality, with the radio model as
the prior: a hop is planned no longer than the distance at which the model's quality
falls to `min_quality`, scaled by `scale`; a drone whose measured quality to the
ground falls under `min_quality` while the plan says it should be fine shrinks the
scale (the radio is worse than the model here), a drone measured well above its
prediction lets it grow back. The points come from a greedy cover over the mesh:
every mission drone is a router, so a drone near one that is connected needs no relay,
and one relay placed where it reaches several drones serves them all (chains form
where one hop is not enough).

Distance mode (`mode="distance"`) is the thesis's baseline (scripts 5.9–5.13, in
`relay.distance`): one chain per drone by distance to the ground alone.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

Point = tuple[float, float]  # (north, east), metres from the ground station
GROUND = "ground"
GOAL_SPEED = 5.0  # m/s: the least speed assumed toward a command's target
SCALE_MIN, SCALE_MAX = 0.4, 1.0
SCALE_DOWN, SCALE_UP = 0.9, 1.02  # per plan: quick to distrust the model, slow to trust it again


@dataclass(frozen=True)
class Params:
    min_quality: float = 0.6
    good_m: float = 60.0  # the radio model (the world's `radio:`): no loss up to here
    lost_m: float = 100.0  # … total loss from here
    base_alt: float = 5.0
    alt_diff: float = 5.0
    step: float = 4.0  # a relay's target is not moved by less than this
    min_separation: float = 5.0  # relays keep this far (horizontally) from each other and the drones they serve
    lookahead_s: float = 20.0  # plan for where the drones will be this much later (a relay's takeoff and flight out)
    margin: float = 0.85  # hops are planned at this share of the reach, for the motion in between

    def __post_init__(self) -> None:
        if not 0 < self.min_quality < 1:
            raise ValueError("min_quality must be between 0 and 1")
        if self.lost_m <= self.good_m:
            raise ValueError("the radio's lost_m must be greater than good_m")


@dataclass(frozen=True)
class Drone:
    """A mission drone as the planner sees it."""

    id: str
    at: Point
    velocity: Point = (0.0, 0.0)  # (north, east) m/s
    goal: Point | None = None  # where its current command takes it
    quality: float | None = None  # measured quality to the ground (through the mesh), if known

    def ahead(self, seconds: float) -> Point:
        """Where it will be `seconds` from now: toward its goal (at least at
        GOAL_SPEED: a drone that has just started is about to speed up), not past it;
        with no goal, along its velocity."""
        if self.goal is not None:
            return toward(self.at, self.goal, max(math.hypot(*self.velocity), GOAL_SPEED) * seconds)
        return self.at[0] + self.velocity[0] * seconds, self.at[1] + self.velocity[1] * seconds


@dataclass(frozen=True)
class Relay:
    id: str
    at: Point
    target: Point | None = None  # the last target it was sent to
    alt: float = 0.0  # the altitude it flies its duty at
    serving: bool = True  # False: sent home, still in the mission (can be called back)


@dataclass(frozen=True)
class Move:
    relay: str
    to: Point
    alt: float


@dataclass
class Plan:
    points: list[Point] = field(default_factory=list)  # where relays are needed
    moves: list[Move] = field(default_factory=list)  # targets to send now
    dispatch: list[tuple[Point, float]] = field(default_factory=list)  # new relays: where and at which altitude
    home: list[str] = field(default_factory=list)  # relays to send home
    scale: float = 1.0  # the model's range scale after this plan's measurements
    served: dict[str, list[str]] = field(default_factory=dict)  # point index (as str) → drones it connects
    notes: list[str] = field(default_factory=list)


def dist(a: Point, b: Point) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def toward(a: Point, b: Point, d: float) -> Point:
    """The point `d` metres from `a` toward `b` (b itself if closer)."""
    length = dist(a, b)
    if length <= d or length == 0:
        return b
    f = d / length
    return a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f


def model_quality(d: float, p: Params) -> float:
    if d <= p.good_m:
        return 1.0
    if d >= p.lost_m:
        return 0.0
    return 1.0 - (d - p.good_m) / (p.lost_m - p.good_m)


def reach(p: Params, scale: float = 1.0) -> float:
    """The planned hop length: where the scaled model's quality is `min_quality`, with
    the margin for motion."""
    return scale * (p.good_m + (1.0 - p.min_quality) * (p.lost_m - p.good_m)) * p.margin


def cover(drones: Mapping[str, Point], hop: float, fixed: Iterable[Point] = ()) -> tuple[list[Point], dict[int, list[str]]]:
    """Relay points that connect every drone to the ground (at (0, 0)) with hops no
    longer than `hop`, greedily: each new point is the candidate in reach of what is
    already connected that connects the most drones (ties: the one closest to the
    ground, so chains stay short). `fixed` are points already connected (none needed).
    Returns the points and, per point index, the drones it brought in."""
    connected: list[Point] = [(0.0, 0.0), *fixed]
    left = dict(drones)
    points: list[Point] = []
    brought: dict[int, list[str]] = {}

    def close_over() -> list[str]:
        """Drones within a hop of anything connected join it (the mesh routes through them)."""
        joined: list[str] = []
        grew = True
        while grew:
            grew = False
            for d, at in sorted(left.items()):
                if any(dist(at, c) <= hop for c in connected):
                    connected.append(at)
                    joined.append(d)
                    del left[d]
                    grew = True
        return joined

    close_over()
    for _ in range(4 * len(drones) + 8):  # each point connects a drone or shortens a chain
        if not left:
            break
        best: tuple[int, float, float, Point] | None = None
        for cand in _candidates(connected, list(left.values()), hop):
            if not any(dist(cand, c) <= hop + 1e-6 for c in connected):
                continue
            gained = sum(1 for at in left.values() if dist(cand, at) <= hop)
            # Most drones connected; else the nearest approach to one still out (a chain
            # step); then the spot nearest the ground.
            key = (gained, -min(dist(cand, at) for at in left.values()), -dist(cand, (0.0, 0.0)), cand)
            if best is None or key[:3] > best[:3]:
                best = key
        assert best is not None  # a point a hop toward any drone always qualifies
        points.append(best[3])
        connected.append(best[3])
        brought[len(points) - 1] = close_over()
    return points, brought


def _candidates(connected: Sequence[Point], targets: Sequence[Point], hop: float) -> Iterable[Point]:
    for c, t in itertools.product(connected, targets):
        yield toward(c, t, hop)  # a chain step
        if dist(c, t) <= 2 * hop:
            yield ((c[0] + t[0]) / 2, (c[1] + t[1]) / 2)  # between the two: both in reach
    for c, (t1, t2) in itertools.product(connected, itertools.combinations(targets, 2)):
        yield _centre(c, t1, t2)  # one relay for two drones (and the node it hangs on)


def _centre(a: Point, b: Point, c: Point) -> Point:
    """The centre of the smallest circle around three points (the Steiner-like spot for
    one relay serving two drones and the node it connects to)."""
    for x, y, z in ((a, b, c), (a, c, b), (b, c, a)):
        mid = ((x[0] + y[0]) / 2, (x[1] + y[1]) / 2)
        if dist(mid, z) <= dist(x, y) / 2:
            return mid
    ax, ay, bx, by, cx, cy = a[0], a[1], b[0], b[1], c[0], c[1]
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-9:  # collinear: the two far ends' midpoint
        far = max(((a, b), (a, c), (b, c)), key=lambda pair: dist(*pair))
        return ((far[0][0] + far[1][0]) / 2, (far[0][1] + far[1][1]) / 2)
    ux = ((ax * ax + ay * ay) * (by - cy) + (bx * bx + by * by) * (cy - ay) + (cx * cx + cy * cy) * (ay - by)) / d
    uy = ((ax * ax + ay * ay) * (cx - bx) + (bx * bx + by * by) * (ax - cx) + (cx * cx + cy * cy) * (bx - ax)) / d
    return ux, uy


def separate(point: Point, others: Iterable[Point], gap: float) -> Point:
    """`point` moved (a few times at most) so that it keeps `gap` from each of `others`."""
    n, e = point
    for _ in range(4):
        moved = False
        for o in others:
            d = dist((n, e), o)
            if d < gap:
                if d < 1e-6:
                    n, e = o[0] - gap, o[1]  # on top of it: step back toward the ground side
                else:
                    f = gap / d
                    n, e = o[0] + (n - o[0]) * f, o[1] + (e - o[1]) * f
                moved = True
        if not moved:
            break
    return n, e


def adjust_scale(scale: float, drones: Sequence[Drone], p: Params, predicted: Mapping[str, float]) -> float:
    """The measured quality against what the plan predicted for each drone."""
    worse = [d for d in drones if d.quality is not None and d.quality < p.min_quality <= predicted.get(d.id, 0.0)]
    if worse:
        return max(SCALE_MIN, scale * SCALE_DOWN)
    if any(d.quality is not None and d.quality >= 0.95 for d in drones) and scale < SCALE_MAX:
        return min(SCALE_MAX, scale * SCALE_UP)
    return scale


def path_quality(at: Point, nodes: Sequence[Point], p: Params, scale: float) -> float:
    """The best quality of any path from `at` to the ground over `nodes` (hop by hop,
    the product of the scaled model's qualities)."""
    everything = [(0.0, 0.0), *nodes]
    best = {i: 0.0 for i in range(len(everything))}
    best[0] = 1.0
    done: set[int] = set()
    while len(done) < len(everything):  # Dijkstra on the product (a maximum, all in [0, 1])
        i = max((j for j in best if j not in done), key=lambda j: best[j])
        done.add(i)
        for j in range(len(everything)):
            if j not in done:
                q = best[i] * model_quality(dist(everything[i], everything[j]) / scale, p)
                best[j] = max(best[j], q)
    return max((best[i] * model_quality(dist(everything[i], at) / scale, p) for i in best), default=0.0)


def plan(drones: Sequence[Drone], relays: Sequence[Relay], p: Params, scale: float = 1.0) -> Plan:
    """What the relays should do now (module docstring)."""
    result = Plan()
    predicted = {d.id: path_quality(d.at, [o.at for o in drones if o.id != d.id] + [r.at for r in relays if r.serving], p, scale)
                 for d in drones}
    scale = adjust_scale(scale, drones, p, predicted)
    result.scale = scale
    hop = reach(p, scale)
    # Plan for the drones where they are and where they are going; a drone measured
    # under min_quality is planned at its worst case (the next hop must come closer).
    wanted: dict[str, Point] = {}
    for d in drones:
        wanted[d.id] = d.at
        later = d.ahead(p.lookahead_s)
        if dist(later, (0.0, 0.0)) > dist(d.at, (0.0, 0.0)):
            wanted[f"{d.id}@later"] = later
    points, brought = cover(wanted, hop)
    for d in drones:
        if d.quality is not None and d.quality < p.min_quality and not any(d.id in b for b in brought.values()):
            result.notes.append(f"{d.id}: measured quality {d.quality:.2f} < {p.min_quality:g}; the radio is worse than the model here")
    # Keep relays clear of the drones they serve and of each other.
    keep_clear = [d.at for d in drones]
    placed: list[Point] = []
    for pt in points:
        placed.append(separate(pt, keep_clear + placed, p.min_separation))
    result.points = placed
    result.served = {str(i): sorted({name.split("@")[0] for name in names}) for i, names in brought.items()}
    _assign(result, relays, p)
    return result


def duty_altitude(index: int, p: Params) -> float:
    """Thesis script 5.9: the first relay at base_alt + alt_diff, the next at base_alt, …"""
    return p.base_alt + (p.alt_diff if index % 2 == 0 else 0.0)


def _assign(result: Plan, relays: Sequence[Relay], p: Params) -> None:
    """Match relays to points, nearest first: serving relays before ones on their way
    home (which are called back before a new drone is dispatched)."""
    free = list(relays)
    pairs = sorted(((not r.serving, dist(r.target or r.at, pt), i, r.id) for i, pt in enumerate(result.points) for r in free))
    taken_points: set[int] = set()
    taken_relays: set[str] = set()
    for _, _, i, rid in pairs:
        if i in taken_points or rid in taken_relays:
            continue
        taken_points.add(i)
        taken_relays.add(rid)
        relay = next(r for r in relays if r.id == rid)
        to = result.points[i]
        if not relay.serving or relay.target is None or dist(relay.target, to) > p.step:
            result.moves.append(Move(rid, to, relay.alt or duty_altitude(i, p)))
    on_duty = len([r for r in relays if r.serving])
    for i, pt in enumerate(result.points):
        if i not in taken_points:
            result.dispatch.append((pt, duty_altitude(on_duty + len(result.dispatch), p)))
    result.home = sorted(r.id for r in relays if r.serving and r.id not in taken_relays)
