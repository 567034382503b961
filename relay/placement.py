"""Where relay drones go (SPEC §8 "Relay", issue 15): pure code, no I/O and no clock.

Everything is in a local frame in metres (north, east) around the ground station, which
is at (0, 0). One call of `plan` takes what the mission knows now — its drones'
positions, motion and the measured link qualities, the relays on duty — and returns
what to do: the relay points the fleet needs, which relay flies to which point (only
when its target moves by more than `step`), how many new relays to dispatch and which
relays to send home.

Measured mode (the default) decides on **measured** quality, with the radio model as
the prior, its range scaled by `scale`: a drone measuring clearly worse than the plan
predicts, after a whole probe window with the drones still and the relays where they
were sent, shrinks the scale (the radio is worse than the model here); good
measurements everywhere let it grow back. A placement is judged by the path the mesh
really takes (`path_quality`: fewest hops over the links that hold, so a lossy
shortcut defeats a relay). Every mission drone is a router, so a drone near one that
is connected needs no relay, and one relay placed where it reaches several drones
serves them all; relays are moved from where they are by a local search and added
(single, or as an even chain) only while they help. ADR 0006 has the measurements.

Distance mode (`mode="distance"`) is the thesis's baseline (scripts 5.9–5.13, in
`relay.distance`): one chain per drone by distance to the ground alone.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

Point = tuple[float, float]  # (north, east), metres from the ground station
GROUND = "ground"
SCALE_MIN, SCALE_MAX = 0.4, 1.0
SCALE_DOWN, SCALE_UP = 0.95, 1.02
# A link losing this share of its packets is up about a sixth of the time (keep-alives
# every 0.5 s, a 2 s lease, a 4-packet handshake retried every second: ADR 0003);
# one losing half stays up for half a minute at a time.
LINK_HOLDS = 0.65
RELEASE_MARGIN = 0.15  # a relay goes home only if the rest keep every spot this far above min_quality
MAX_RELAYS = 8  # per plan
STEADY_PLANS = 12  # a probe window (10 s) and then some, at one plan a second
DRIFT_S = 3.0  # a drone with no goto/move is planned this far ahead along its velocity
LIFT_STEP_M = 0.5
MAX_LIFT_M = 100.0


@dataclass(frozen=True)
class Params:
    min_quality: float = 0.6
    good_m: float = 60.0  # the radio model (the world's `radio:`): no loss up to here
    lost_m: float = 100.0  # … total loss from here
    base_alt_m: float = 5.0  # the lower of the two duty altitudes (m above the ground station)
    alt_diff_m: float = 5.0  # the upper one is this much higher
    step_m: float = 4.0  # a relay's target is not moved by less than this
    min_separation_m: float = 5.0  # relays keep this far (horizontally) from each other and the drones they serve
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
    alt: float | None = None  # m above the ground it flies at (the higher of now and its goal); None: on the ground

    def ahead(self, seconds: float) -> Point:
        """Where its velocity takes it in `seconds`."""
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
    steady: int = 0  # plans in a row with the drones still and the relays where sent (give it to the next plan)
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


def settled(relays: Sequence[Relay], p: Params) -> bool:
    """Every serving relay is where it was sent: what the drones measure is this geometry's."""
    return all(r.target is None or dist(r.at, r.target) <= 2 * p.step_m for r in relays if r.serving)


def adjust_scale(scale: float, drones: Sequence[Drone], p: Params, predicted: Mapping[str, float]) -> float:
    """The measured quality against what the plan predicts for each drone: worse
    shrinks the model's range, good everywhere lets it grow back."""
    worse = [d for d in drones if d.quality is not None and d.quality < p.min_quality and d.quality < predicted.get(d.id, 0.0) - 0.1]
    if worse:
        return max(SCALE_MIN, scale * SCALE_DOWN)
    if not worse and any(d.quality is not None for d in drones) and all(d.quality is None or d.quality >= 0.95 for d in drones) \
            and scale < SCALE_MAX:
        return min(SCALE_MAX, scale * SCALE_UP)
    return scale


def link_quality(a: Point, b: Point, p: Params, scale: float) -> float | None:
    """The scaled model's quality of a link between two spots, None where no link holds."""
    d = dist(a, b) / scale
    return None if d >= p.good_m + LINK_HOLDS * (p.lost_m - p.good_m) else model_quality(d, p)


def path_quality(at: Point, nodes: Sequence[Point], p: Params, scale: float) -> float:
    """The quality of the path the mesh takes from `at` to the ground over `nodes`.

    The mesh's routers run link-state routing on hop count (ADR 0003): traffic takes
    the fewest hops over the links that are up, lossy or not. A link that loses most
    of its packets rarely stays up (its keep-alives miss the lease) or opens again (its
    handshake must get through): links are counted while they lose less than
    LINK_HOLDS of them. A relay only helps where it is not short-cut by a
    longer, lossy link; among the fewest-hop paths the worst is counted (which one the
    mesh picks is not ours to choose)."""
    return Mesh(nodes, p, scale).quality_at(at)


class Mesh:
    """The mesh's hop levels from the ground over `nodes` (breadth first, links that
    hold), each node's quality at its level; then any spot's path quality (path_quality)
    without walking the mesh again. A spot joins at the first level with a node it links
    to, at the worst such link: what a walk that stops at the spot gives, since a spot
    never carries traffic for the nodes. link_quality and model_quality are inlined here,
    the same arithmetic in the same order: this is most of a relay plan's CPU."""

    def __init__(self, nodes: Sequence[Point], p: Params, scale: float) -> None:
        self._good, self._lost, self._scale = p.good_m, p.lost_m, scale
        self._holds = p.good_m + LINK_HOLDS * (p.lost_m - p.good_m)
        points = [(0.0, 0.0), *nodes]
        quality = {0: 1.0}
        level = [(0.0, 0.0, 1.0)]  # (x, y, quality) of each node at this many hops
        self._levels: list[Callable[[float, float], float | None]] = []  # a spot's best link into each level
        while level:
            best = self._best(level)
            self._levels.append(best)
            nxt: list[int] = []
            for j, (xj, yj) in enumerate(points):
                if j not in quality and (q := best(xj, yj)) is not None:
                    quality[j] = q
                    nxt.append(j)
            level = [(points[j][0], points[j][1], quality[j]) for j in nxt]

    def _best(self, nodes: list[tuple[float, float, float]]) -> Callable[[float, float], float | None]:
        """The worst path quality through a link from one of `nodes` to a spot, None
        where no link holds."""
        good, lost, scale, holds, hypot = self._good, self._lost, self._scale, self._holds, math.hypot

        def best(xj: float, yj: float) -> float | None:
            worst: float | None = None
            for xi, yi, qi in nodes:
                d = hypot(xi - xj, yi - yj) / scale
                if d >= holds:
                    continue
                q = 1.0 if d <= good else 0.0 if d >= lost else 1.0 - (d - good) / (lost - good)
                value = qi * q
                if worst is None or value < worst:
                    worst = value
            return worst
        return best

    def quality_at(self, at: Point) -> float:
        x, y = at
        for best in self._levels:
            found = best(x, y)
            if found is not None:
                return found
        return 0.0


def wanted_spots(d: Drone, p: Params) -> list[Point]:
    """Where a drone must stay connected: where it is, and along its way to its goal
    (the relays fly out while it does) or, without a goal, where it will be."""
    far = d.goal if d.goal is not None else d.ahead(DRIFT_S)  # no command: only where its speed takes it soon
    if dist(far, (0.0, 0.0)) <= dist(d.at, (0.0, 0.0)) or dist(far, d.at) < 1.0:
        return [d.at]
    n = min(8, max(1, math.ceil(dist(d.at, far) / 20.0)))
    return [d.at] + [toward(d.at, far, dist(d.at, far) * k / n) for k in range(1, n + 1)]


@dataclass
class _Scene:
    """What a set of relay points is judged against."""

    drones: Sequence[Drone]
    wanted: list[tuple[str, Point]]
    p: Params
    scale: float
    start: Sequence[Point] = ()  # the serving relays' targets before this plan

    def qualities(self, points: Sequence[Point]) -> list[float]:
        meshes: dict[str, Mesh] = {}  # one per drone whose spots are judged (its own position left out)
        for name, _ in self.wanted:
            if name not in meshes:
                meshes[name] = Mesh([*(d.at for d in self.drones if d.id != name), *points], self.p, self.scale)
        return [meshes[name].quality_at(spot) for name, spot in self.wanted]

    def worst(self, points: Sequence[Point]) -> float:
        return min(self.qualities(points), default=1.0)

    def score(self, points: Sequence[Point]) -> tuple[float, float, float, float]:
        """Over every wanted spot: minus the total shortfall under min_quality (each spot
        brought up counts), minus how far the spots still cut off are from anything
        connected (a chain's first relays count before it reaches), the worst quality up
        to a margin over the bar (beyond it nothing is worth a move), minus how far the
        relays move from their targets (they stay put when all else is equal)."""
        qs = self.qualities(points)
        connected = self.connected(points)
        gap = sum(min(dist(spot, c) for c in connected) for (_, spot), q in zip(self.wanted, qs, strict=True) if q == 0.0)
        moved = sum(dist(a, b) for a, b in zip(points, self.start, strict=False))
        return (-sum(max(0.0, self.p.min_quality - q) for q in qs), -gap,
                min(min(qs, default=1.0), self.p.min_quality + RELEASE_MARGIN), -moved)

    def connected(self, points: Sequence[Point]) -> list[Point]:
        """The ground and every node with a path to it."""
        done = [(0.0, 0.0)]
        left = [*points, *(d.at for d in self.drones)]
        grew = True
        while grew:
            grew = False
            for n in list(left):
                if any(link_quality(n, c, self.p, self.scale) is not None for c in done):
                    done.append(n)
                    left.remove(n)
                    grew = True
        return done

    def clear(self, point: Point, others: Sequence[Point]) -> Point:
        return separate(point, [d.at for d in self.drones] + list(others), self.p.min_separation_m)

    def improve(self, points: list[Point]) -> list[Point]:
        """Local search: move one point at a time by shrinking strides while the worst
        spot (then the mean) gets better."""
        best = self.score(points)
        for stride in (16.0, 8.0, 4.0, 2.0):
            for _ in range(12):
                better = False
                for i in range(len(points)):
                    for k in range(8):
                        a = math.pi * k / 4
                        moved = (points[i][0] + stride * math.cos(a), points[i][1] + stride * math.sin(a))
                        trial = [*points[:i], self.clear(moved, points[:i] + points[i + 1:]), *points[i + 1:]]
                        s = self.score(trial)
                        if s > best:
                            points, best, better = trial, s, True
                if not better:
                    break
        return points

    def add(self, points: list[Point], room: int) -> list[Point]:
        """More points (at most `room`): the candidate that scores best among single
        points (a hop from anything connected toward a spot still short of quality,
        halfway there, or the centre of it, another such spot and the node) and evenly
        spaced chains of up to three from a connected node to the worst spot."""
        hop = reach(self.p, self.scale)
        nodes = self.connected(points)
        qs = self.qualities(points)
        short = [spot for (_, spot), q in zip(self.wanted, qs, strict=True) if q < self.p.min_quality]
        if not short or room < 1:
            return points
        singles = [toward(c, t, hop) for c in nodes for t in short] + [toward(c, t, dist(c, t) / 2) for c in nodes for t in short]
        singles += [_centre(c, t1, t2) for c in nodes for t1, t2 in itertools.combinations(short, 2)]  # one relay for two
        options = [[c] for c in singles]
        worst = min(short, key=lambda spot: qs[[w for _, w in self.wanted].index(spot)])
        for c in nodes:
            for k in range(2, min(3, room) + 1):
                options.append([toward(c, worst, dist(c, worst) * i / (k + 1)) for i in range(1, k + 1)])
        best: tuple[tuple[float, ...], list[Point]] | None = None
        for extra in options:
            placed = list(points)
            for pt in extra:
                placed.append(self.clear(pt, placed))
            scored = (self.score(placed), placed)
            if best is None or scored[0] > best[0]:
                best = scored
        return best[1] if best is not None else points


def plan(drones: Sequence[Drone], relays: Sequence[Relay], p: Params, scale: float = 1.0, spare: int = MAX_RELAYS,
         steady: int = 0) -> Plan:
    """What the relays should do now (module docstring); `spare`: how many more relays
    the fleet has (those on their way home count among them); `steady`: the last
    plan's count of steady plans in a row. Measurements cover a window of probes
    (10 s by default), so the model is only judged by them once the drones have been
    still and the relays where they were sent for a whole window (STEADY_PLANS)."""
    result = Plan()
    serving = [r for r in relays if r.serving]
    current = [r.target or r.at for r in serving]
    predicted = {d.id: path_quality(d.at, [o.at for o in drones if o.id != d.id] + [r.at for r in serving], p, scale) for d in drones}
    still = settled(relays, p) and all(math.hypot(*d.velocity) < 1.0 for d in drones)
    result.steady = steady + 1 if still else 0
    if result.steady >= STEADY_PLANS:
        adjusted = adjust_scale(scale, drones, p, predicted)
        if adjusted != scale:
            scale, result.steady = adjusted, 0  # the next judgement waits for a window under the new plan
    result.scale = scale
    scene = _Scene(drones, [(d.id, spot) for d in drones for spot in wanted_spots(d, p)], p, scale, current)
    if scene.worst(current) >= p.min_quality:
        points = current
        # Enough as they are: one relay may go home if the others keep every spot well above the bar.
        if serving:
            without = max((scene.worst(current[:i] + current[i + 1:]), i) for i in range(len(current)))
            if without[0] >= min(1.0, p.min_quality + RELEASE_MARGIN):
                points = current[:without[1]] + current[without[1] + 1:]
                result.home = [serving[without[1]].id]
                serving = serving[:without[1]] + serving[without[1] + 1:]
        result.points = points
        _assign(result, serving, [r for r in relays if not r.serving], p, keep=True, flying=_flying(drones))
        return result
    points = scene.improve(list(current))
    while scene.worst(points) < p.min_quality and len(points) < len(serving) + spare:
        more = scene.improve(scene.add(points, len(serving) + spare - len(points)))
        if scene.score(more) <= scene.score(points):
            break  # one more relay does not help (a lossy link short-cuts it)
        points = more
    worst = scene.worst(points)
    if worst < p.min_quality:
        result.notes.append(f"best placement reaches quality {worst:.2f} < {p.min_quality:g} with {len(points)} relays")
    for d in drones:
        if d.quality is not None and d.quality < p.min_quality:
            result.notes.append(f"{d.id}: measured quality {d.quality:.2f} < {p.min_quality:g}")
    result.points = points
    _assign(result, serving, [r for r in relays if not r.serving], p, keep=False, flying=_flying(drones))
    return result


def duty_altitude(index: int, p: Params, flying: Sequence[float] = ()) -> float:
    """Thesis script 5.9: the first relay at base_alt + alt_diff, the next at base_alt, …
    Both levels are lifted together, if need be, until they are min_separation above or
    below every altitude the served drones fly at: a drone flying
    back toward the ground passes right where its relays hover (0.1 m on real packets)."""
    lift = 0.0
    while lift < MAX_LIFT_M and not all(_alt_clear(p.base_alt_m + lift + k * p.alt_diff_m, flying, p) for k in (0, 1)):
        lift += LIFT_STEP_M
    return p.base_alt_m + lift + (p.alt_diff_m if index % 2 == 0 else 0.0)


def _kept_altitude(r: Relay, index: int, p: Params, flying: Sequence[float]) -> float:
    """A relay keeps its altitude unless a drone flies at it; then it takes the lifted level of `index`."""
    return r.alt if _alt_clear(r.alt, flying, p) else duty_altitude(index, p, flying)


def _alt_clear(alt: float, flying: Sequence[float], p: Params) -> bool:
    return all(abs(alt - f) >= p.min_separation_m for f in flying)


def _flying(drones: Sequence[Drone]) -> list[float]:
    return [d.alt for d in drones if d.alt is not None]


def _assign(result: Plan, serving: Sequence[Relay], returning: Sequence[Relay], p: Params, keep: bool,
            flying: Sequence[float] = ()) -> None:
    """The first points are the serving relays' (in order); the rest go to relays on
    their way home, nearest first (called back before a new drone is dispatched), then
    to new relays. A relay is moved only when its point moved by more than `step`."""
    for i, (r, pt) in enumerate(zip(serving, result.points, strict=False)):
        alt = _kept_altitude(r, i, p, flying)
        if keep and alt != r.alt:
            result.moves.append(Move(r.id, r.target or r.at, alt))  # it stays, above (or below) the drones
        elif not keep and (r.target is None or dist(r.target, pt) > p.step_m or alt != r.alt):
            result.moves.append(Move(r.id, pt, alt))
    extra = result.points[len(serving):]
    back = list(returning)
    for j, pt in enumerate(extra):
        if back:
            r = min(back, key=lambda r: dist(r.at, pt))
            back.remove(r)
            alt = _kept_altitude(r, len(serving) + j, p, flying)
            result.moves.append(Move(r.id, pt, alt))
        else:
            result.dispatch.append((pt, duty_altitude(len(serving) + len(result.dispatch), p, flying)))
