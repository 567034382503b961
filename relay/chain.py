"""Relay chains on hops the relays proved (issue 32): pure code, no I/O and no clock.

The measured mode of ADR 0006 places relays by a radio model whose range it corrects;
this one places them only on hops a relay measured to hold (`mode="chain"`). Why: a
hop holds a 3-s gap only while it loses at most ~10 % of its packets (`bench/relay_hop.py`),
and what a drone reports while it moves is a window of the distances it crossed. A hop
is therefore proven by a relay that *stays*: on its spot for a whole probe window
(DWELL_S), its reported loss (the datagrams' share lost, SPEC §8) averaging at most
PROVEN_LOSS over the reports made there, and its mean RTT within SPIKE_MS of the best
seen (no retransmission: where the loss came through other drones' links, a query
window, the transport hides it as delay).

- **Learning the hop** (`relay/hop.py`): one probe relay flies out along the first
  worker's way to a trial hop (the model's `good_m`, then GROWTH x what held, then
  halfway to what failed), dwells, and comes back to the last proven spot by itself
  (its task bundle says so): a trial beyond reach costs a detour, never a drone. The
  workers are held near the laptop until the hop is known.
- **Chains**: then every worker gets its own chain from the laptop toward where the
  script sends it, a relay every proven hop (3-D: relays hover at the duty altitude,
  the laptop stands on the ground), added as the worker's goal needs them and sent home
  from the far end when the worker no longer needs them.
- **The leash**: a worker's goto goes at most as far as a proven node covers (the laptop
  or a relay on its spot, within `lo` in 3-D); the rest of the way is flown as relays
  arrive. A worker held while its chain needs a relay and no drone is free is `stuck`,
  named with the relays missing. (A local frame in metres, north and east of the laptop.)"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from dronefleet.relay.hop import Reach, bottleneck
from dronefleet.relay.placement import Point, dist, toward
from dronefleet.relay.rules import DEFAULT, Separation
from dronefleet.relay.ways import segment_distance
from dronefleet.sim.radio import HOLDING_LOSS

ORIGIN: Point = (0.0, 0.0)
PROBE = "probe"

MARGIN = 0.97  # chains are laid at this share of the proven hop
DWELL_S = 11.0  # on its spot this long: a whole 10-probe window measured there
ON_SPOT_M = 3.0
LAUNCH_CLEAR_M = 15.0  # a relay is sent when the last one has flown this far from the drones on the ground
LAUNCH_TIMEOUT_S = 40.0  # a relay assigned this long ago and still on the ground never took off: another is sent
CLEAR_AHEAD_PARKED = 3  # a held drone beside a parked one is let on this many parked clearances toward its goal
MIN_STEP_M = 8.0  # a relay's spot is at least this far (across) from the node before it
PROVEN_LOSS = 0.05  # a hop whose loss averaged at most this over the dwell holds (half of what keeps a 3-s gap)
SPIKE_MS = 30.0  # a window's mean RTT this far above the best seen held two retransmissions (+200 ms / 10 each)
RELEASE_AFTER = 5  # plans in a row without need before a relay goes home
DISPATCH_TIMEOUT_S = 30.0  # a relay asked for and not assigned by then is asked for again
RESEND_S = 45.0  # a probe heard but not on its trial spot by then is sent there again …
MAX_RESENDS = 2  # … this many times; then the trial counts as failed
SLOT_RESEND_S = 90.0  # … a chain relay, by then
STRETCH_AFTER_S = 30.0  # a chain lacking a relay with none free this long stretches its hops (`_stretch`)


def _done(w: Worker) -> bool:
    """A worker on the ground going nowhere needs no relay."""
    return w.alt < 1.0 and w.goal is None


def flat(hop: float, dz: float) -> float:
    """The horizontal length of a 3-D hop of `hop` metres across `dz` metres of height."""
    return math.sqrt(max(0.0, hop * hop - dz * dz))


def covers(nodes: Iterable[tuple[Point, float]], p: Point, alt: float, reach: float) -> bool:
    """Whether a drone at `p`, `alt` metres up, is within `reach` (3-D) of one of `nodes`."""
    return any(math.hypot(dist(p, n), alt - z) <= reach for n, z in nodes)


@dataclass(frozen=True)
class Worker:
    id: str
    at: Point
    alt: float  # metres above the ground station it flies at
    goal: Point | None  # where the script wants it now (a held goto's goal too)
    home: Point | None = None  # where its return (its lost-link failsafe's too) takes it
    # in the air now, whatever `alt` says: a goto down to its home is flown toward 0 m, and
    # its way was left out of the columns a relay may climb through (it passed one 3.7 m off)
    airborne: bool = False

    @property
    def aloft(self) -> bool:
        return self.alt >= 1.0 or self.airborne


@dataclass(frozen=True)
class Seen:
    """What the plugin sees of a relay on duty."""

    at: Point
    alt: float  # metres above the ground station
    loss: float | None  # its link window to the ground (None: no window yet)
    rtt_ms: float | None
    fresh: bool = True  # heard lately (else where it is and its window are old news)
    hops: int | None = None  # its window's answers came over its own link (1), some through others (2), or unknown


@dataclass
class Slot:
    spot: Point
    relay: str | None = None  # None: asked for, no drone yet
    asked_at: float = 0.0  # when it was asked for, or sent to this spot
    on_spot_since: float | None = None
    hop_m: float = 0.0  # a probe's trial hop (0: measured, the next one not sent yet)
    resends: int = 0  # a probe's trial sent again (its move refused, or it came back unmeasured)
    again: bool = False  # its relay failed: to be asked for again, in place
    losses: list[float] = field(default_factory=list)  # a probe's link loss reports on its spot (its dwell's window)


@dataclass
class ChainPlan:
    # (slot key, spot, hold seconds or 0, where the relay takes off: a free drone's spot
    # whose column no flying drone comes near; None: any free drone, none stands known)
    dispatch: list[tuple[str, Point, float, Point | None]] = field(default_factory=list)
    moves: list[tuple[str, Point, float]] = field(default_factory=list)  # (relay, spot, seconds to dwell before coming back; 0: stay)
    home: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)  # relays assigned that never took off: the plan goes on without them
    notes: list[str] = field(default_factory=list)


class Chains:
    """The state of `mode="chain"` across plans (one per mission)."""

    def __init__(self, duty_alt: float, first_trial: float | None = None, rules: Separation = DEFAULT) -> None:
        self.duty_alt = duty_alt
        self.rules = rules
        self.first_trial = first_trial
        self.reach = Reach()
        self.probe: Slot | None = None
        self.safe: Point | None = None  # where the probe waits between trials (its last proven spot)
        self.chains: dict[str, list[Slot]] = {}
        self.idle: list[str] = []  # relays on duty with no spot (the probe, once the hop is known)
        self.base_rtt: float | None = None
        self.leaving: dict[str, int] = {}
        self.stuck: dict[str, str] = {}
        self.stretched: dict[str, float] = {}  # worker → the hop its chain stretched to (`_stretch`)
        self.short_since: dict[str, float] = {}  # worker → since when its chain lacks a relay and none is free
        self.covered: dict[str, list[tuple[Point, float]]] = {}  # worker → proven nodes (spot, alt)
        self.parked: list[Point] = []  # where a relay may take off through the served drones' level
        self.flying: dict[str, Point] = {}  # the served drones in the air, where they are (last plan)
        self.grounded: list[Point] = []  # the drones on the ground (one may be the next relay)
        self.spares: list[Point] = []  # where the free drones stand that may be sent as relays
        self.site: Point | None = None  # the spare the next relay is to take off from (`_launch_clear`)
        self.legs: list[tuple[Point, Point]] = []  # the served drones in the air: where each is, how far it may go

    # ---- what the plugin asks -------------------------------------------------------

    def joined(self, key: str, relay: str) -> None:
        """The plugin assigned `relay` to the slot it was asked for under `key`."""
        slot = self._slot(key)
        if slot is not None and slot.relay is None:
            slot.relay = relay
            slot.again = False

    def failed(self, relay: str, now: float) -> None:
        """`relay` cannot do its duty (its duty bundle failed, it never took off): its
        slot is asked for again in place (a probe, sent again); the plugin sends it home."""
        if self.probe is not None and self.probe.relay == relay:
            self.probe = None
            if self.reach.trials == 0:
                self.reach.first_tried = False  # the model's hop was never tried: the next probe tries it
        for chain in self.chains.values():
            for slot in chain:
                if slot.relay == relay:
                    # asked for again at the next plan (as if its ask had timed out)
                    slot.relay, slot.again, slot.on_spot_since = None, True, None
                    slot.asked_at = now - DISPATCH_TIMEOUT_S - 1.0
        if relay in self.idle:
            self.idle.remove(relay)

    def dropped(self, relay: str) -> None:
        """A relay the plugin lost (its assignment failed, it was revoked)."""
        if self.probe is not None and self.probe.relay == relay:
            self.probe = None
        for chain in self.chains.values():
            chain[:] = [s for s in chain if s.relay != relay]
        if relay in self.idle:
            self.idle.remove(relay)

    def relays(self) -> set[str]:
        """The relays the plan holds: the probe, those on a chain's slot, the idle."""
        return set(self._spots())

    def _spots(self) -> dict[str, list[Point]]:
        """Each relay the plan holds and the spots it holds it to: a chain slot's; the
        probe's trial spot and where it waits between trials; where an idle one waits."""
        spots: dict[str, list[Point]] = {}
        for c in self.chains.values():
            for s in c:
                if s.relay is not None:
                    spots.setdefault(s.relay, []).append(s.spot)
        waits = [self.safe] if self.safe is not None else []
        if self.probe is not None and self.probe.relay is not None:
            spots.setdefault(self.probe.relay, []).extend([self.probe.spot, *waits])
        for relay in self.idle:
            spots.setdefault(relay, []).extend(waits)
        return spots

    def launching(self) -> bool:
        """A relay asked for and not assigned yet: any drone on the ground may take off."""
        asked = self.probe is not None and self.probe.relay is None
        return asked or any(s.relay is None for c in self.chains.values() for s in c)

    def allowed(self, worker: str, at: Point, alt: float, goal: Point) -> Point:
        """How far toward `goal` the worker may fly now: the last point of the straight
        way there that a proven node covers (the goal itself when all of it is)."""
        if not self.reach.known and not self._proven_enough(goal, alt):
            # While the probe measures, each drone waits where it took off (none crosses
            # another's way) — but never beside a drone on the ground: that drone may be
            # the next relay to climb, and no relay launches while a flying drone is that
            # close to the drones on the ground (`_launch_clear`). Drones standing closer
            # than the parked clearance (a row at the spawn gap) held every launch for ever.
            return self._clear_ahead(worker, at, goal)
        nodes = self.covered.get(worker) or [(ORIGIN, 0.0)]
        reach = self._hop(worker)

        def inside(p: Point) -> bool:
            return covers(nodes, p, alt, reach)

        if not inside(at):  # drifted out (or its nodes went): back toward the nearest node
            n, z = min(nodes, key=lambda nz: dist(at, nz[0]))
            return toward(n, at, flat(reach, alt - z) * 0.95)
        best = at
        for k in range(1, int(dist(at, goal)) + 1):
            p = toward(at, goal, float(k))
            if not inside(p):
                break
            best = p
        else:
            if inside(goal):
                return goal
        while not self._clear(best) and dist(best, at) > 0.5:  # held short of a parked drone, not over it
            best = toward(best, at, 1.0)
        return best if self._clear(best) else self._clear_ahead(worker, at, goal, inside)

    def _release_probe(self, workers: Sequence[Worker], out: ChainPlan) -> None:
        """The probe of a hop never bracketed (links that never fail) goes home once every
        worker is done, as released relays do (it hovered to the time limit)."""
        probe = self.probe
        if probe is None or probe.relay is None or not all(_done(w) for w in workers):
            return
        if self._released(probe.relay):
            out.home.append(probe.relay)
            self.probe = None

    def _released(self, relay: str, may_go: bool = True) -> bool:
        """One more plan in a row that `relay` is not needed: True (its count done) once
        that has been RELEASE_AFTER plans and `may_go` (no other relay crossing the levels)."""
        self.leaving[relay] = self.leaving.get(relay, 0) + 1
        if self.leaving[relay] >= RELEASE_AFTER and may_go:
            del self.leaving[relay]
            return True
        return False

    def _hop(self, worker: str) -> float:
        """The hop `worker`'s chain is laid on and the worker kept within: the proven hop
        at MARGIN, or the longer one its chain stretched to (`_stretch`)."""
        return self.stretched.get(worker, self.reach.lo * MARGIN)

    def _enough_for(self, workers: Sequence[Worker]) -> bool:
        """Whether the hop proven so far reaches every worker's goal: measuring further
        proves nothing anyone needs (on links that never fail nothing brackets it)."""
        return all(w.goal is None or self._proven_enough(w.goal, w.alt) for w in workers)

    def _proven_enough(self, goal: Point, alt: float) -> bool:
        """Whether the hop proven so far reaches `goal` from the laptop as chains lay it
        (at MARGIN of it): then the probe stops, and the worker may go though the hop is
        not bracketed (on a link that never fails it never is: the worker waited for ever)."""
        return dist(ORIGIN, goal) <= flat(self.reach.lo * MARGIN, alt)

    def _clear_ahead(self, worker: str, at: Point, goal: Point, inside: Callable[[Point], bool] = lambda p: True) -> Point:
        """`at` if no drone on the ground stands within the parked clearance of it; else the
        first point toward `goal` that is clear of them and of the other flying drones
        (a goto that close to another's spot is refused, SPEC §11), and `inside` what
        covers it; else `at`."""
        if self._clear(at):
            return at
        others = [q for w, q in self.flying.items() if w != worker]
        for k in range(1, int(CLEAR_AHEAD_PARKED * self.rules.parked_m) + 1):
            p = toward(at, goal, float(k))
            if dist(p, at) < k - 0.5:  # the goal is nearer: nowhere clear ahead
                break
            if not inside(p):
                break
            if self._clear(p) and all(dist(p, q) >= self.rules.parked_m for q in others):
                return p
        return at

    # ---- one plan ---------------------------------------------------------------------

    def plan(self, now: float, workers: Sequence[Worker], seen: Mapping[str, Seen], spare: int,
             others: Sequence[tuple[Point, float]] = (), spares: Sequence[Point] = ()) -> ChainPlan:
        """`workers`: the mission's drones to keep connected; `seen`: the relays on duty
        (by id); `spare`: drones free to be sent as relays; `others`: every other node
        of the mesh (spot, altitude), which a probe's traffic may pass through; `spares`:
        where the free drones stand (a relay is sent from one whose column is clear)."""
        out = ChainPlan()
        # drones on the ground, and relays climbing from it through the served drones' level
        self.grounded = [at for at, alt in others if alt < 1.0]
        self.spares = [at for at in spares if any(dist(at, q) < 0.5 for q in self.grounded)]
        self.parked = self.grounded + [o.at for o in seen.values() if o.alt < self.duty_alt - 1.0]
        self.legs = [(w.at, w.home or w.at) for w in workers if w.aloft]  # while the probe measures, they wait
        self.flying = {w.id: w.at for w in workers if w.aloft}
        for s in seen.values():
            if s.fresh and s.rtt_ms is not None and (self.base_rtt is None or s.rtt_ms < self.base_rtt):
                self.base_rtt = s.rtt_ms
        self._expire(now)
        self.stuck.clear()
        if not self.reach.known:
            nodes = [(w.at, w.alt) for w in workers] + list(others)
            self._learn(now, nodes, seen, out)
            if not self.reach.known:
                self._probe(now, workers, nodes, spare, out)
                for w in workers:
                    self.covered[w.id] = [(ORIGIN, 0.0)]
                self._release_probe(workers, out)
                return out
        if self.probe is not None:  # the hop is known: the probe waits for a spot
            if self.probe.relay is not None:
                self.idle.append(self.probe.relay)
            out.notes.append(f"the radio holds hops of {self.reach.lo:.0f} m (fails at {self.reach.hi:.0f} m)"
                             if self.reach.hi is not None else f"the radio holds hops of {self.reach.lo:.0f} m")
            self.probe = None
        for w in workers:
            self.covered[w.id] = self._nodes(now, self.chains.setdefault(w.id, []), seen, out)
        self.legs = [(w.at, w.home or self.allowed(w.id, w.at, w.alt, w.goal or w.at)) for w in workers if w.aloft]
        free = spare
        for w in workers:
            free = self._extend(now, w, seen, free, out)
        self._release(workers, seen, out)
        return out

    def _slot(self, key: str) -> Slot | None:
        if key == PROBE:
            return self.probe
        worker, _, index = key.rpartition("#")
        chain = self.chains.get(worker, [])
        i = int(index) if index.isdigit() else -1
        return chain[i] if 0 <= i < len(chain) else None

    def _expire(self, now: float) -> None:
        if self.probe is not None and self.probe.relay is None and now - self.probe.asked_at > DISPATCH_TIMEOUT_S:
            self.probe = None
        for chain in self.chains.values():
            while chain and chain[-1].relay is None and now - chain[-1].asked_at > DISPATCH_TIMEOUT_S:
                chain.pop()

    def _learn(self, now: float, nodes: Sequence[tuple[Point, float]], seen: Mapping[str, Seen], out: ChainPlan) -> None:
        """The probe on its spot for a whole window proves its own hop to the laptop when
        every answer came over that link (its report's `hops`; a ring of spares around
        the laptop made every trial prove only the hop through one of them: 40 m on a
        radio good to 56), else the bottleneck of its best path to the
        laptop; or, failing, that its own hop to the laptop does not hold
        (were that link lossless it would be up and, one hop being fewest, taken)."""
        slot = self.probe
        if slot is None or slot.relay is None or slot.hop_m == 0.0 or slot.relay not in seen:
            return
        s = seen[slot.relay]
        if self._never_took_off(slot.relay, s, slot.asked_at, now, out):
            return
        lost = not s.fresh and now - slot.asked_at > DISPATCH_TIMEOUT_S
        there = s.fresh and self._on_spot(s, slot.spot)
        if there and slot.on_spot_since is None:
            slot.on_spot_since, slot.losses = now, []
        elif there and s.loss is not None:
            slot.losses.append(s.loss)  # reported after it arrived: measured on the spot
        elif not there and not lost:
            if not s.fresh and slot.on_spot_since is not None and now - slot.on_spot_since >= DWELL_S:
                lost = True  # gone silent on its spot
            else:
                slot.on_spot_since = None if s.fresh else slot.on_spot_since
                if s.fresh and now - slot.asked_at > RESEND_S and slot.resends < MAX_RESENDS:
                    slot.asked_at = now  # its move was refused or lost: again
                    slot.resends += 1
                    out.moves.append((slot.relay, slot.spot, DWELL_S + 4.0))
                    return
                if not (s.fresh and now - slot.asked_at > RESEND_S):
                    return
                lost = True  # sent again and again and never measured there: that hop does not hold
        if not lost and (slot.on_spot_since is None or now - slot.on_spot_since < DWELL_S):
            return
        own = math.hypot(dist(slot.spot, ORIGIN), self.duty_alt)
        loss = sum(slot.losses) / len(slot.losses) if slot.losses else None
        # heard on its spot with no retransmission in its round trips: its loss is the path's
        steady = not lost and loss is not None and s.rtt_ms is not None and s.rtt_ms <= (self.base_rtt or 0.0) + SPIKE_MS
        clean = steady and loss is not None and loss <= PROVEN_LOSS
        measured = own
        if steady:
            if s.hops == 1:  # every answer over its own link: that hop, whatever stands nearer
                measured = math.hypot(dist(s.at, ORIGIN), s.alt)
            else:  # its traffic may have taken a shorter hop through another node
                others = list(nodes) + [(o.at, o.alt) for rid, o in seen.items() if rid != slot.relay]
                measured = bottleneck((s.at, s.alt), others)
        if clean:
            self.reach.held(measured)
            self.safe = slot.spot
            out.notes.append(f"probe {slot.relay}: a hop of {measured:.0f} m held")
        else:
            self.reach.failed(own)
            if steady and loss is not None and loss <= HOLDING_LOSS:
                self.reach.holding(measured)
            out.notes.append(f"probe {slot.relay}: a hop of {own:.0f} m did not hold "
                             f"({'not heard' if lost else f'loss {loss if loss is None else round(loss, 3)}, rtt {s.rtt_ms} ms'})")
        slot.on_spot_since, slot.losses = None, []
        slot.hop_m, slot.resends = 0.0, 0

    def _probe(self, now: float, workers: Sequence[Worker], nodes: Sequence[tuple[Point, float]], spare: int,
               out: ChainPlan) -> None:
        """Send the probe to the next trial hop, in the direction where a clean window
        would prove the most (away from the other nodes, which its traffic could take)."""
        if self._enough_for(workers):
            return  # nobody needs to go beyond what is known to hold
        if self.probe is not None and (self.probe.relay is None or self.probe.hop_m != 0.0):
            return  # asked for, or out on a trial
        if self.probe is None and spare <= 0:
            for w in workers:
                self.stuck[w.id] = "no free drone to measure the radio with"
            return
        if self.probe is None and not self._launch_clear({}, out):
            return
        trial = self.reach.trial(self.first_trial)
        spot = self._trial_spot(trial, nodes)
        if self.safe is None:  # not over a drone on the ground either: it hovers there between trials
            self.safe = self._off_parked(ORIGIN, toward(ORIGIN, spot, flat(self.reach.lo, self.duty_alt)), {})
        if self.probe is None:
            self.probe = Slot(spot, None, now, hop_m=trial)
            out.dispatch.append((PROBE, spot, DWELL_S + 4.0, self.site))
            out.notes.append(f"probe: trying a hop of {trial:.0f} m")
        else:
            assert self.probe.relay is not None
            self.probe.spot, self.probe.hop_m, self.probe.asked_at = spot, trial, now
            out.moves.append((self.probe.relay, spot, DWELL_S + 4.0))
            out.notes.append(f"probe {self.probe.relay}: trying a hop of {trial:.0f} m")

    def _trial_spot(self, trial: float, nodes: Sequence[tuple[Point, float]]) -> Point:
        """`trial` from the laptop (3-D), in the direction where a clean window proves the
        most: its best path's longest hop, whichever node its traffic takes."""
        r = flat(trial, self.duty_alt)
        spots = [(r * math.cos(math.radians(b)), r * math.sin(math.radians(b))) for b in range(0, 360, 15)]
        clear = [p for p in spots if self._clear(p)] or spots
        return max(clear, key=lambda p: bottleneck((p, self.duty_alt), nodes))

    def _never_took_off(self, relay: str, o: Seen, asked_at: float, now: float, out: ChainPlan) -> bool:
        """On the ground LAUNCH_TIMEOUT_S after it was asked for: given up (`failed`)."""
        if not (o.fresh and o.alt < 1.0 and now - asked_at > LAUNCH_TIMEOUT_S):
            return False
        out.failed.append(relay)
        self.failed(relay, now)
        return True

    def _on_spot(self, o: Seen, spot: Point) -> bool:
        return dist(o.at, spot) <= ON_SPOT_M and abs(o.alt - self.duty_alt) <= self.rules.level_band_m

    def _clear(self, p: Point) -> bool:
        """Not over (within the parked clearance across of) a drone on the ground, which
        may take off there."""
        return all(dist(p, q) >= self.rules.parked_m for q in self.parked)

    def _nodes(self, now: float, chain: Sequence[Slot], seen: Mapping[str, Seen],
               out: ChainPlan) -> list[tuple[Point, float]]:
        """The laptop and the relays of the chain on their spots, in order, up to the first
        gap; a relay heard elsewhere long after it was sent is sent again."""
        nodes = [(ORIGIN, 0.0)]
        gap = False
        for s in chain:
            o = seen.get(s.relay) if s.relay is not None else None
            if o is not None and s.relay is not None and self._never_took_off(s.relay, o, s.asked_at, now, out):
                o = None
            there = o is not None and self._on_spot(o, s.spot)
            s.on_spot_since = (s.on_spot_since or now) if there else None
            if o is not None and s.relay is not None and not there and o.fresh and now - s.asked_at > SLOT_RESEND_S:
                s.asked_at = now  # its move went wrong
                out.moves.append((s.relay, s.spot, 0.0))
            gap = gap or not there
            if not gap:
                nodes.append((s.spot, self.duty_alt))
        return nodes

    def _extend(self, now: float, w: Worker, seen: Mapping[str, Seen], free: int, out: ChainPlan) -> int:
        chain = self.chains[w.id]
        if w.alt < 1.0 and w.goal is None:
            return free  # on the ground, going nowhere: nothing to keep it connected for
        again = next((i for i, s in enumerate(chain) if s.again), None)
        if again is not None:  # a relay of the chain failed: its slot first
            if free <= 0 or now - chain[again].asked_at <= DISPATCH_TIMEOUT_S or not self._launch_clear(seen, out):
                return free
            chain[again].asked_at = now
            out.dispatch.append((f"{w.id}#{again}", chain[again].spot, 0.0, self.site))
            return free - 1
        goal = w.goal or w.at
        hop = self._hop(w.id)
        planned = [(ORIGIN, 0.0)] + [(s.spot, self.duty_alt) for s in chain]
        if covers(planned, goal, w.alt, hop):
            self.short_since.pop(w.id, None)
            return free  # the chain (once its relays are there) reaches the goal
        if chain and chain[-1].relay is None:
            return free  # one asked for, not assigned yet
        last, last_z = planned[-1]
        spot = self._off_parked(last, toward(last, goal, max(MIN_STEP_M, flat(hop, self.duty_alt - last_z))), seen)
        key = f"{w.id}#{len(chain)}"
        if self.idle:
            if self._crossing(seen, out):
                return free  # it climbs to its lane to move: after the one crossing now
            relay = self.idle.pop(0)
            chain.append(Slot(spot, relay, now))
            out.moves.append((relay, spot, 0.0))
            return free
        if free > 0:
            self.short_since.pop(w.id, None)
        elif now - self.short_since.setdefault(w.id, now) >= STRETCH_AFTER_S and not self._crossing(seen, out) \
                and self._stretch(now, w, goal, out):
            return free
        if not self._launch_clear(seen, out):
            return free  # the last relay sent is still climbing out over the others' takeoff spots
        if free <= 0:
            need, at, z = 0, last, last_z
            while not covers([(at, z)], goal, w.alt, hop) and need < 100:
                at, z, need = toward(at, goal, max(MIN_STEP_M, flat(hop, self.duty_alt - z))), self.duty_alt, need + 1
            self.stuck[w.id] = (f"{w.id} needs {need} more relay(s) to reach its goal and no drone is free" if need < 100 else
                                f"the radio holds hops of {self.reach.lo:.0f} m, too short to reach relays hovering "
                                f"{self.duty_alt:g} m up: relays cannot bring {w.id} to its goal")
            return free
        chain.append(Slot(spot, None, now))
        out.dispatch.append((key, spot, 0.0, self.site))
        return free - 1

    def _stretch(self, now: float, w: Worker, goal: Point, out: ChainPlan) -> bool:
        """`w`'s chain has lacked a relay with no drone free for STRETCH_AFTER_S: if hops
        no longer than a window measured to keep a 3-s gap reach its goal with the relays
        it has, its chain is laid on the shortest such hop from now on — each relay moved
        out along its leg, where it keeps clear of other chains and of the drones on the
        ground. False: it stays as it is (held, and named with the relays it lacks)."""
        chain = self.chains[w.id]
        longest = self.reach.holds * MARGIN
        if w.id in self.stretched or longest <= self.reach.lo * MARGIN or any(s.relay is None for s in chain):
            return False
        if self._relaid(chain, goal, w.alt, longest) is None:
            return False
        lo, hi = self.reach.lo * MARGIN, longest  # the shortest hop that reaches it, within 0.5 m
        while hi - lo > 0.5:
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if self._relaid(chain, goal, w.alt, mid) is not None else (mid, hi)
        spots = self._relaid(chain, goal, w.alt, hi)
        assert spots is not None
        others = [sl.spot for c, ch in self.chains.items() if c != w.id for sl in ch]
        if not all(self._clear(p) and all(dist(p, q) >= self.rules.relays_apart_m for q in others) for p in spots):
            return False
        self.stretched[w.id] = hi
        self.short_since.pop(w.id, None)
        for slot, p in zip(chain, spots, strict=True):
            if dist(p, slot.spot) > 0.5 and slot.relay is not None:
                slot.spot, slot.asked_at, slot.on_spot_since = p, now, None
                out.moves.append((slot.relay, p, 0.0))
        out.notes.append(f"{w.id}: no drone is free for its chain; hops of {hi:.0f} m from now on "
                         f"(a window at {self.reach.holds:.0f} m kept a 3-s gap)")
        return True

    def _relaid(self, chain: Sequence[Slot], goal: Point, alt: float, hop: float) -> list[Point] | None:
        """The chain's relays each as far out along its leg as `hop` (3-D), if they then
        cover `goal` (a worker `alt` up); else None."""
        spots: list[Point] = []
        back_old, back_new, z = ORIGIN, ORIGIN, 0.0
        for slot in chain:
            length = dist(back_old, slot.spot)
            d = flat(hop, self.duty_alt - z)
            ux, uy = ((slot.spot[0] - back_old[0]) / length, (slot.spot[1] - back_old[1]) / length) if length else (0.0, 0.0)
            spots.append((back_new[0] + ux * d, back_new[1] + uy * d))
            back_old, back_new, z = slot.spot, spots[-1], self.duty_alt
        nodes = [(ORIGIN, 0.0)] + [(p, self.duty_alt) for p in spots]
        return spots if covers(nodes, goal, alt, hop) else None

    def _off_parked(self, back: Point, spot: Point, seen: Mapping[str, Seen]) -> Point:
        """`spot`, or nearer `back`, or aside, until it is not over a drone on the ground
        (which would climb into the relay hovering there when it takes off) nor within
        the relays' clearance of another relay's spot or of a relay on duty (chains toward
        workers in near directions begin side by side; two relays came within 3.5 m)."""
        taken = [sl.spot for c in self.chains.values() for sl in c] + [o.at for rid, o in seen.items() if rid not in self.idle]

        def room(p: Point) -> float:  # 1 or more: clear of both
            return min([dist(p, q) / self.rules.parked_m for q in self.parked] + [dist(p, q) / self.rules.relays_apart_m for q in taken]
                       + [math.inf])

        length = dist(back, spot)
        along = [toward(back, spot, length - k) for k in range(int(length - MIN_STEP_M) + 1)]
        ux, uy = ((spot[0] - back[0]) / length, (spot[1] - back[1]) / length) if length else (1.0, 0.0)
        aside = [(spot[0] - uy * k * sign, spot[1] + ux * k * sign) for k in range(1, 13) for sign in (1, -1)]
        nearer = [toward(back, spot, float(k)) for k in range(int(min(length, MIN_STEP_M)) + 1)]  # down to `back`
        candidates = along + aside + nearer
        # the first with room; with none (a ring of drones on the ground around the laptop), the roomiest
        return next((p for p in candidates if room(p) >= 1.0), max(candidates, key=room))

    def _launch_clear(self, seen: Mapping[str, Seen], out: ChainPlan) -> bool:
        """Whether a relay may take off now, and from where (`site`). It climbs through
        every lower level (ADR 0006), so it takes off from a free drone's spot whose
        column no served drone is over, going over, or going home over (the parked clearance
        across), of those the one farthest from them; and only while no other relay
        crosses the levels near that column: to a spot (near when its way passes within
        LAUNCH_CLEAR_M of it), coming home, or sent in this plan (it goes first). With
        no free drone's spot known, every drone on the ground counts as the one."""
        self.site = None
        if out.moves or any(s.relay is None and not s.again for c in self.chains.values() for s in c):
            return False
        ways = {relay: spots for relay, spots in self._spots().items() if relay not in self.idle}
        for rid, o in seen.items():
            if o.fresh and o.alt <= 1.0 and rid in ways:
                return False  # sent, not yet up: one takes off at a time
            if rid not in ways and o.alt > 1.0:
                return False  # coming home (heard or not)
        sites = self.spares or self.grounded
        if not sites:
            return True  # no drone known on the ground: whichever goes, nothing stands near it

        def room(q: Point) -> float:
            return min([segment_distance((*a, 0.0), (*b, 0.0), (*q, 0.0), (*q, 0.0)) for a, b in self.legs] + [math.inf])

        clear = [q for q in sites if room(q) >= self.rules.parked_m and not self._crossed(q, seen, ways)]
        if not clear or (not self.spares and len(clear) < len(sites)):
            return False  # not knowing which drone goes, every one must be clear
        self.site = max(clear, key=lambda q: (room(q), -dist(q, ORIGIN))) if self.spares else None
        return True

    def _crossed(self, q: Point, seen: Mapping[str, Seen], ways: Mapping[str, list[Point]]) -> bool:
        """A relay off its duty level flies to a spot past `q` within LAUNCH_CLEAR_M across."""
        for rid, o in seen.items():
            if not o.fresh or o.alt <= 1.0 or abs(o.alt - self.duty_alt) <= self.rules.level_band_m or rid not in ways:
                continue  # on the ground, on its duty level, or not the plan's
            if any(segment_distance((*o.at, 0.0), (*to, 0.0), (*q, 0.0), (*q, 0.0)) < LAUNCH_CLEAR_M for to in ways[rid]):
                return True
        return False

    def _crossing(self, seen: Mapping[str, Seen], out: ChainPlan) -> bool:
        """Whether a relay is crossing the levels now, or is about to: one off its duty
        level (coming home, climbing out, moving between spots) or being sent. Relays
        cross the levels one at a time (ADR 0006): a relay climbing to its lane to be
        moved passed 1.1 m under one flying home on a lower lane."""
        held = self._spots()
        # one going home counts out of reach too (a relay flying home lost its link, and the
        # next one went); one of the plan's counts until it is on its spot (a relay climbing
        # out passed the duty level as another was sent home over it), heard or not: one
        # unheard since it was last seen off its spot may be anywhere on its way (a relay
        # lost its link climbing out, and another was sent home across its level)
        # (an idle one hovering on the duty level is not crossing it, wherever it waits)
        return any(o.alt > 1.0 if rid not in held else
                   abs(o.alt - self.duty_alt) > self.rules.level_band_m if rid in self.idle
                   else not any(self._on_spot(o, p) for p in held[rid])
                   for rid, o in seen.items()) or self.launching() or bool(out.dispatch) or bool(out.moves)

    def _release(self, workers: Sequence[Worker], seen: Mapping[str, Seen], out: ChainPlan) -> None:
        """The last relay of a chain its worker no longer needs goes home — when no
        other relay is climbing out or coming home: one crossing the levels at a time (a
        relay flying home on its level passed over one climbing from the ground, 1.4 m
        apart)."""
        hop = self.reach.lo * MARGIN
        crossing = self._crossing(seen, out)
        for w in workers:
            chain = self.chains.get(w.id, [])
            if not chain or chain[-1].relay is None:
                continue
            before = [(ORIGIN, 0.0)] + [(s.spot, self.duty_alt) for s in chain[:-1]]
            places = [w.at] + ([w.goal] if w.goal is not None else [])
            # on the ground going nowhere, it needs none (one landed at a home beyond the
            # laptop's hop kept its relay on duty to the time limit)
            needed = not _done(w) and not all(covers(before, p, w.alt, hop) for p in places)
            rid = chain[-1].relay
            if needed:
                self.leaving.pop(rid, None)
                continue
            if self._released(rid, not crossing):
                crossing = True
                chain.pop()
                out.home.append(rid)
        # An idle relay (the probe, once the hop is known) that no chain took goes home
        # once every worker is done (it hovered to the time limit).
        for rid in list(self.idle) if all(_done(w) for w in workers) else []:
            if self._released(rid, not crossing):
                crossing = True
                self.idle.remove(rid)
                out.home.append(rid)
