"""`relays`, what the bundled `relay` plugin (and any script) uses to ask the pure
placement of `relay/` where relay drones go: the drone wrappers become points in metres
around the ground station, the plan's points become positions again.

    plan = relays.plan(served_drones, on_duty, relay_drones, ground, min_quality=0.6, …)
    plan.moves     # [(relay_id, position, duty altitude above home)]
    plan.dispatch  # [(position, duty altitude)]: new relays needed
    plan.home      # [relay_id]: no longer needed
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from dronefleet.mission.lifecycle import assignment as a
from dronefleet.mission.lifecycle.delivery import Leash
from dronefleet.mission.script import units
from dronefleet.mission.script.drone import handle
from dronefleet.mission.script.position import Position, as_position
from dronefleet.relay import chain as chains
from dronefleet.relay import distance as baseline
from dronefleet.relay import placement, rounds, ways
from dronefleet.relay.rules import DEFAULT_SEPARATION_M, Separation
from dronefleet.schemas.commands import DEFAULT_RETURN_ALT_M
from dronefleet.sim.projection import LocalFrame

if TYPE_CHECKING:
    from dronefleet.mission.lifecycle.mission import Mission

AIRBORNE_M = 1.0  # above home: flying


class Frame:
    """Metres north/east of the ground station (sim.projection's local plane)."""

    def __init__(self, ground: Any) -> None:
        g = as_position(ground)
        self.plane = LocalFrame(g.lat, g.lon)

    def local(self, p: Any) -> placement.Point:
        p = as_position(p)
        return self.plane.to_local(p.lat, p.lon)

    def world(self, pt: placement.Point) -> Position:
        return Position(*self.plane.to_global(*pt))


@dataclass(frozen=True)
class RelayPlan:
    moves: list[tuple[str, Position, float]]
    dispatch: list[tuple[Position, float]]
    home: list[str]
    scale: float
    steady: int
    notes: list[str]


@dataclass(frozen=True)
class ChainOrders:
    """One plan of mode "chain": what the plugin does now."""

    moves: list[tuple[str, Position, float]]  # (relay, spot, seconds a probe dwells there before coming back; 0: stays)
    # (spot, dwell as above, the slot's key for `chain_joined`, what to assign: the free
    # drone that may relay nearest the spot it is to take off from)
    dispatch: list[tuple[Position, float, str, Any]]
    home: list[str]
    notes: list[str]
    failed: list[str]  # relays assigned that never took off: their slots are asked for again


def _goal(drone: Any) -> Position | None:
    cmd = drone.cmd
    return cmd.target if cmd is not None and cmd.name in ("goto", "move") and isinstance(cmd.target, Position) else None


def flight_altitude(drone: Any) -> float | None:
    """Metres above its home a mission drone flies at: where its takeoff or goto takes
    it (a return: its altitude), else where it is (not while it climbs or lands: a
    level passed through is not one flown at); None on the ground or landing."""
    cmd, home = drone.cmd, drone.home
    if cmd is not None and cmd.name in ("takeoff", "return") and isinstance(cmd.target, (int, float)):
        return float(cmd.target)  # the return's altitude: it flies home there
    if cmd is not None and cmd.name == "land":
        return None
    goal = _goal(drone)
    if goal is not None and goal.alt is not None and home is not None and home.alt is not None:
        return goal.alt - home.alt
    t = handle(drone).telemetry()
    return t.position.rel_alt if t.position is not None and t.position.rel_alt > AIRBORNE_M else None


class Relays:
    """The `relays` name in scripts; `mission` (None where no mission runs: a plugin's
    load check) gives it the free drones and the clock."""

    def __init__(self, mission: Mission | None = None) -> None:
        self._mission = mission
        self._chains: chains.Chains | None = None
        self._frame: Frame | None = None
        self._served: dict[str, Any] = {}
        self._rules = Separation()  # mode="chain": from the plugin's min_separation (`chain`)
        self._ways = ways.Ways(rules=self._rules)
        self._rounds = rounds.PlanRounds()

    def now(self) -> float:
        """Seconds on the mission's clock (monotonic; virtual in fast time)."""
        return self._mission.clock.monotonic() if self._mission is not None else 0.0

    def new_round(self, drone_id: str) -> bool:
        """`drone_id` was heard: whether a plan is due now (relay/rounds.py)."""
        return self._rounds.due(drone_id, self.now())

    def metres(self, value: Any, what: str = "distance") -> float:
        """A length input (`5*m` or a plain number of metres) as metres."""
        return units.length(value, what)

    def spare(self) -> int:
        """How many drones of the fleet are free to be dispatched as relays now."""
        return len(self._mission.free_candidates()) if self._mission is not None else 0

    def duty_altitude(self, index: int, served: Sequence[Any], **inputs: Any) -> float:
        """Script 5.9's alternating duty altitudes (index 0: base_alt + alt_diff, 1:
        base_alt, …), lifted clear of the altitudes the `served` drones fly at."""
        flying = [a for a in map(flight_altitude, served) if a is not None]
        return placement.duty_altitude(index, self.params(**inputs), flying)

    def above_flights(self, served: Sequence[Any], margin: Any) -> float:
        """Metres above home that clear by `margin` every level a served drone flies:
        its flight altitude, and the level its return takes it home at (the agents'
        default return altitude: `home(d)` after the survey flew its drone under relays
        3 m above it). A fleet configured with a higher `return_altitude` is not known
        here (About does not carry it)."""
        flying = [a for a in map(flight_altitude, served) if a is not None]
        return round(max([*flying, DEFAULT_RETURN_ALT_M]) + units.length(margin, "margin"), 1)

    def params(self, **inputs: Any) -> placement.Params:
        """The planner's parameters from the plugin's inputs (`base_alt=5*m`: metres)."""
        metres = {"base_alt": "base_alt_m", "alt_diff": "alt_diff_m", "step": "step_m", "min_separation": "min_separation_m",
                  "good_m": "good_m", "lost_m": "lost_m"}
        return placement.Params(**{metres.get(k, k): units.length(v, k) if k in metres else v for k, v in inputs.items()})

    def plan(self, served: Sequence[Any], on_duty: Mapping[str, Mapping[str, Any]], drones: Mapping[str, Any], ground: Any,
             scale: float = 1.0, spare: int | None = None, steady: int = 0, **inputs: Any) -> RelayPlan:
        """`served`: the mission's drones to keep connected; `on_duty`: relay id →
        {"target": position or None, "alt": duty altitude, "serving": bool};
        `drones`: relay id → its wrapper (for where it is now); `spare`: how many new
        relays may be dispatched (default: the free drones of the fleet)."""
        frame = Frame(ground)
        params = self.params(**inputs)
        mine = []
        for d in served:
            t = handle(d).telemetry()
            goal = _goal(d)
            link = d.link
            mine.append(placement.Drone(
                d.id, frame.local(d.position), (t.velocity.north, t.velocity.east),
                frame.local(goal) if goal is not None else None, link.quality if link is not None else None,
                flight_altitude(d),
            ))
        relays = [placement.Relay(rid, frame.local(drones[rid].position),
                                frame.local(duty["target"]) if duty.get("target") is not None else None,
                                float(duty.get("alt", 0.0)), bool(duty.get("serving", True)))
                  for rid, duty in on_duty.items()]
        returning = sum(1 for r in relays if not r.serving)
        result = placement.plan(mine, relays, params, scale, spare=(self.spare() if spare is None else spare) + returning,
                              steady=steady)
        return RelayPlan(
            moves=[(m.relay, frame.world(m.to), m.alt) for m in result.moves],
            dispatch=[(frame.world(pt), alt) for pt, alt in result.dispatch],
            home=result.home, scale=result.scale, steady=result.steady, notes=result.notes,
        )

    # ---- the thesis's baseline (mode="distance") ------------------------------------

    def needs_follower(self, drone: Any, ground: Any, n_relays: int, target_dist: Any) -> bool:
        frame = Frame(ground)
        goal = _goal(drone)
        return baseline.requires_relay(frame.local(drone.position), frame.local(goal) if goal else None, drone.speed,
                                       n_relays, units.length(target_dist, "target_dist"))

    def follow_step(self, other: Any, me: Any, ground: Any, target_dist: Any, alt: float | None = None,
                    others: Sequence[Any] = (), min_separation: Any = 5.0) -> tuple[Position, float, float, bool]:
        """Where the follower `me` goes now: (target, speed, bearing, other returning).
        With `alt` (its duty altitude AMSL) the target keeps `min_separation` (3-D) from
        the drones `others`, where they are and where their goto takes them."""
        frame = Frame(ground)
        goal = _goal(other)
        o, g, m = frame.local(other.position), (frame.local(goal) if goal else None), frame.local(me.position)
        td = units.length(target_dist, "target_dist")
        to = baseline.new_target(o, g, m, td)
        if alt is not None:
            near: list[tuple[placement.Point, float]] = []
            for d in others:
                here = d.position
                near.append((frame.local(here), here.alt if here.alt is not None else alt))
                there = _goal(d)
                if there is not None:
                    near.append((frame.local(there), there.alt if there.alt is not None else near[-1][1]))
            to = baseline.keep_clear(to, alt, near, units.length(min_separation, "min_separation"))
        return frame.world(to), baseline.new_speed(other.speed), baseline.new_bearing(o, g, m), baseline.returning(o, g, td)

    # ---- chains on proven hops (mode="chain", relay/chain.py) -----------------------

    def level_gap(self, min_separation: Any) -> float:
        """mode="chain": metres between the levels relays fly out and home on, and from
        their duty level to the served drones' highest (relay/rules.py)."""
        return self.separation(min_separation).level_gap_m

    def separation(self, min_separation: Any) -> Separation:
        """The relay's separation rules for a `min_separation` input (`5*m` or metres)."""
        metres = units.length(min_separation, "min_separation")
        if metres != self._rules.separation_m:
            try:
                self._rules = Separation(metres)
            except ValueError as exc:
                raise ValueError(f"relay: {exc}") from None
            self._ways.rules = self._rules
            if self._chains is not None:
                self._chains.rules = self._rules
        return self._rules

    def chain(self, served: Sequence[Any], drones: Mapping[str, Any], ground: Any, duty_alt: float,
              good_m: float | None = None, heard_s: float = 2.5, min_separation: Any = DEFAULT_SEPARATION_M) -> ChainOrders:
        """One plan of `mode="chain"`: `served` the mission's drones, `drones` relay id →
        wrapper for every relay on duty, `duty_alt` the relays' altitude above the ground
        station, `good_m` the radio model's good range (the first hop tried),
        `min_separation` what every clearance derives from (relay/rules.py). Leashes the
        served drones' gotos to what the chains cover (see `leash`)."""
        if self._chains is None:
            self._chains = chains.Chains(duty_alt, good_m, rules=self.separation(min_separation))
            self._frame = Frame(ground)
            if self._mission is not None:
                self._mission.delivery.leash = self.leash
        frame = self._frame
        assert frame is not None
        now = self.now()
        self._served = {d.id: d for d in served}
        workers = []
        for d in served:
            goal = _goal(d)
            held = self._mission.delivery.leashed.get(d.id) if self._mission is not None else None
            if held is not None:
                goal = Position(held[0], held[1], held[2])
            level = flight_altitude(d)  # where it flies, not the levels it climbs or lands through
            cmd, home = d.cmd, d.home
            height = _above(d, d.position.alt) or 0.0
            workers.append(chains.Worker(d.id, frame.local(d.position), level if level is not None else height,
                                         frame.local(goal) if goal is not None else None,
                                         frame.local(home) if cmd is not None and cmd.name == "return" and home else None,
                                         airborne=height > AIRBORNE_M))
        seen = {}
        for rid, d in drones.items():
            link = d.link
            fresh = self._mission is not None and self._mission.heard_within(rid, heard_s)
            seen[rid] = chains.Seen(frame.local(d.position), _above(d, d.position.alt) or 0.0,
                                    link.loss if link is not None else None, link.rtt_ms if link is not None else None,
                                    fresh, link.hops if link is not None else None)
        result = self._chains.plan(now, workers, seen, self.spare(), self._mesh_nodes(frame, set(seen) | set(self._served)),
                                   self._spare_spots(frame))
        return ChainOrders(
            moves=[(rid, frame.world(pt), hold) for rid, pt, hold in result.moves],
            dispatch=[(frame.world(pt), hold, key, self._launcher(frame, site)) for key, pt, hold, site in result.dispatch],
            home=result.home, notes=result.notes, failed=result.failed,
        )

    def _spare_spots(self, frame: Frame) -> list[chains.Point]:
        """Where the free drones stand that `any_relay` would take first (those declared
        for it, else the auxiliary ones, else any that may relay)."""
        if self._mission is None:
            return []
        able = [(a.relay_preference(c), c.lat, c.lon) for c in self._mission.free_candidates()
                if c.relay and c.lat is not None and c.lon is not None]
        best = min((rank for rank, _, _ in able), default=None)
        return [frame.local(Position(lat, lon)) for rank, lat, lon in able if rank == best]

    @staticmethod
    def _launcher(frame: Frame, site: chains.Point | None) -> a.Request:
        """A drone that may relay; the one nearest `site` when the plan named where."""
        if site is None:
            return a.AnyRelay()
        p = frame.world(site)
        return a.AllOf((a.AnyRelay(), a.Near(p.lat, p.lon)))

    def _mesh_nodes(self, frame: Frame, besides: set[str]) -> list[tuple[chains.Point, float]]:
        """Every other drone the ground knows (spot, metres above field level): all route."""
        return [((x, y), alt) for drone_id, (x, y, alt) in self._everyone(frame).items() if drone_id not in besides]

    def chain_joined(self, key: str, relay: Any) -> None:
        if self._chains is not None:
            self._chains.joined(key, relay.id)

    def chain_dropped(self, relay_id: str) -> None:
        if self._chains is not None:
            self._chains.dropped(relay_id)

    def chain_failed(self, relay_id: str) -> None:
        """The relay cannot do its duty (its duty bundle failed): its slot is asked for again."""
        if self._chains is not None:
            self._chains.failed(relay_id, self.now())

    def probe_safe(self) -> Position | None:
        """Where the chain's probe comes back to after a trial."""
        if self._chains is None or self._chains.safe is None or self._frame is None:
            return None
        return self._frame.world(self._chains.safe)

    def leash(self, drone_id: str, lat: float, lon: float, alt: float | None) -> Leash | None:
        """Where a served drone's goto to (lat, lon, alt AMSL) may go now: None for all
        the way, else (lat, lon) of where it may go and why not further: the edge of
        what its chain covers (with, when no drone is free for the relays it needs,
        `stuck` naming them) or another drone's way (relay/ways.py)."""
        ch, frame, d = self._chains, self._frame, self._served.get(drone_id)
        if ch is None or frame is None or d is None or drone_id not in ch.covered:
            return None
        here = _above(d, d.position.alt) or 0.0
        # A leg short of a lower goal keeps the drone's level (the descent is the last leg's):
        # judged at the goal's, a worker on its way home to the field was held for good.
        above = max(_above(d, alt) or 0.0, here) if alt is not None else here
        goal = frame.local(Position(lat, lon))
        at = frame.local(d.position)
        allowed = ch.allowed(drone_id, at, above, goal)
        end, other = self._ways.clear(drone_id, (*at, here), (*allowed, above or here), self._everyone(frame),
                                      set(self._served), self.now(), ch.relays(), ch.launching())
        if chains.dist(end[:2], goal) < 0.5:
            return None
        cut = other is not None and chains.dist(end[:2], allowed) >= 0.5  # short of the chain's edge: another's way
        edge = frame.world(end[:2])
        return (edge.lat, edge.lon, None if cut else ch.stuck.get(drone_id),
                f"out of {other}'s way" if cut else "at the edge of its relay chain")

    def landing_spot(self, relay: Any) -> Position:
        """Where a relay going home comes down: its home, or the nearest spot around it
        (8, 16, 24 m out) clear of every drone in the air by the way clearance and of
        those on the ground by the parked one (relay/rules.py; a relay on duty may hover over the home of
        one sent out before it)."""
        frame = self._frame
        assert frame is not None, "landing_spot: mode chain only"
        home = frame.local(relay.home)
        others = [v for k, v in self._everyone(frame).items() if k != relay.id]

        def clear(pt: chains.Point) -> bool:
            return all(chains.dist(pt, (x, y)) >= (self._rules.way_m if z > AIRBORNE_M else self._rules.parked_m)
                       for x, y, z in others)

        ring = [(home[0] + r * math.cos(math.radians(b)), home[1] + r * math.sin(math.radians(b)))
                for r in (8.0, 16.0, 24.0) for b in range(0, 360, 30)]
        return frame.world(next((pt for pt in [home, *ring] if clear(pt)), home))

    def clear_below(self, relay: Any) -> bool:
        """No drone flying below `relay` is within the way clearance across of its column,
        nor comes within it on its way while the relay comes down (relay/ways.py
        `descent_clear`): it may come down."""
        frame = self._frame
        assert frame is not None, "clear_below: mode chain only"
        heard = self._heard()
        if relay.id not in heard:
            return True
        below = [(self._local(frame, t), (t.velocity.north, t.velocity.east)) for k, t in heard.items() if k != relay.id]
        return ways.descent_clear(self._local(frame, heard[relay.id]), below, self._rules.way_m)

    def _heard(self) -> dict[str, Any]:
        """Every drone the ground knows with a position: its last telemetry."""
        if self._mission is None:
            return {}
        registry = self._mission.station.registry
        out = {}
        for drone_id in registry.ids():
            t = registry.telemetry(drone_id)
            if t is not None and t.position is not None:
                out[drone_id] = t
        return out

    @staticmethod
    def _local(frame: Frame, t: Any) -> tuple[float, float, float]:
        """Where a drone is (local metres, metres above field level), from its telemetry."""
        return (*frame.local(Position(t.position.lat, t.position.lon)), max(0.0, t.position.rel_alt))

    def _everyone(self, frame: Frame) -> dict[str, tuple[float, float, float]]:
        """Where every drone the ground knows is (local metres, metres above field level)."""
        return {drone_id: self._local(frame, t) for drone_id, t in self._heard().items()}


def _above(drone: Any, alt: float | None) -> float | None:
    """An altitude (AMSL) as metres above the drone's home (the field's level)."""
    home = drone.home
    if alt is None or home is None or home.alt is None:
        return None
    return alt - home.alt
