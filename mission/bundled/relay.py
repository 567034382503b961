"""Keep every drone of the mission connected through relay drones (SPEC §8, issue 15).

Chain mode (the default, `relay/chain.py`, ADR 0006): a probe relay measures how long
a hop holds, then every worker gets a chain of relays from the laptop toward where its
goto goes, one every proven hop, and flies only as far as relays on their spots cover
(the leash); relays go home from the far end when no longer needed, and a worker that
needs more relays than the fleet has ends the mission `requirements` naming them.

Measured mode (the first design) places relays by the radio model corrected by the
link quality the drones measure; distance mode is the thesis's one chain per drone.

    enable("relay")                                       # mode="chain"
    enable("relay", mode="measured", min_quality=0.6, base_alt=5*m, alt_diff=5*m, step=4*m)
    enable("relay", mode="distance", target_dist=50*m)    # the thesis's baseline

`ground=[lat, lon]` is the ground station (default: the first served drone's home);
`good_m`/`lost_m` the radio model the plan starts from (the world's `radio:`).

A relay on duty is part of the link (issue 32): it flies its spot as a task bundle
whose `on_link_loss` is `continue`, so its own lost-link failsafe does not pull it off
duty when the chain behind it breaks. The bundle holds the spot for DUTY_S and is
renewed while the plugin still plans; a relay the plugin no longer renews (the ground
gone for that long) ends its duty and its agent's lost-link policy brings it home.
A relay's refused or failed command is the plugin's problem: logged, never the
mission's failure (the mission's `setback`).
"""

duty = {}  # relay id -> {"target": position, "alt": metres above home, "serving": bool, "ready": bool}
crew = {}  # relay id -> its drone wrapper
served = {}  # mission drone id -> wrapper (every mission drone that is not a relay)
state = {"scale": 1.0, "steady": 0, "ground": None, "dispatching": 0, "followed": [],
         "leaving": {}, "duty": None, "until": {}, "lanes": {}, "gone": set(), "failures": {}}
MODES = ("chain", "measured", "distance")
RELEASE_AFTER = 5  # plans in a row that find a relay not needed before it is sent home
steps = step  # the bundle steps' builder: the input `step` (a length) takes its name once enabled
DUTY_S = 120  # a duty bundle holds the relay's spot this long ...
RENEW_S = 60  # ... and is renewed when less than this is left
CHAIN_DUTY_S = 600  # mode="chain": a relay's bundle holds its spot this long (renewed too)
LAND_WAIT_S = 60  # mode="chain": a relay over its landing spot waits this long at most for the air below to clear
FAILED_KEPT_S = 30  # mode="chain": a relay whose duty failed stays assigned this long, so another is sent


def ground_spot(drone):
    if state["ground"] is None:
        state["ground"] = position(ground[0], ground[1]) if ground else drone.home
    return state["ground"]


def speed_for(relay, target):
    """Out to a far spot at full speed; following, relative to the fastest drone served."""
    if relay.position.distance(target) > 30 * m:
        return 10 * m / s
    fastest = max([d.speed for d in served.values()] + [0])
    return min(10 * m / s, max(5 * m / s, fastest * 1.5))


def fly(relay):
    """Take off to the duty altitude, then to the latest spot (moves sent meanwhile
    only updated it), or straight back if it was sent home meanwhile."""
    arm(relay)
    takeoff(relay, duty[relay.id]["alt"] * m)
    duty[relay.id]["ready"] = True
    if duty[relay.id]["serving"]:
        go(relay)
    else:
        come_back(relay)


def on_duty(relay):
    """Still serving: a move started as its own subroutine may run after the relay was sent home."""
    return relay.id in duty and duty[relay.id]["serving"]


def go(relay):
    """Fly to the duty spot and hold it, as a bundle that keeps flying through a lost link."""
    if not on_duty(relay):
        return
    d = duty[relay.id]
    d["until"] = relays.now() + DUTY_S
    spot = steps.move(to=d["target"], alt=relay.home.alt + d["alt"], speed=speed_for(relay, d["target"]))
    push(relay, [spot, steps.wait(DUTY_S * s)], on_link_loss="continue", timeout=(DUTY_S + 300) * s)


def recall(relay):
    cancel(relay)  # a return to launch refuses a goto: stop it first
    go(relay)


def dispatch(spot, alt):
    relay = assign(any_relay)
    state["dispatching"] -= 1
    crew[relay.id] = relay
    duty[relay.id] = {"target": spot, "alt": alt, "serving": True, "ready": False}
    print(f"{relay.id}: relay duty at {alt:g} m, serving the mission's drones")
    fly(relay)


def send_home(relay):
    duty[relay.id]["serving"] = False
    print(f"{relay.id}: relay no longer needed, returning")
    if duty[relay.id]["ready"]:  # else fly() brings it back once it has taken off
        come_back(relay)


def come_back(relay):
    home(relay)
    if relay.id in duty and not duty[relay.id]["serving"]:  # not called back meanwhile
        del duty[relay.id]
        del crew[relay.id]
        revoke(relay)


def new_round(drone):
    """One plan per round of the drones heard, at most every 0.9 s (relay/rounds.py)."""
    return relays.new_round(drone.id)


def measured(drone):
    # No plan while a relay is being assigned.
    if not new_round(drone) or state["dispatching"]:
        return
    plan = relays.plan(list(served.values()), duty, crew, ground_spot(drone), state["scale"], steady=state["steady"],
                       min_quality=min_quality, base_alt=base_alt, alt_diff=alt_diff, step=step,
                       min_separation=min_separation, good_m=good_m, lost_m=lost_m)
    state["scale"], state["steady"] = plan.scale, plan.steady
    moved = [rid for rid, _, _ in plan.moves]
    for rid, spot, alt in plan.moves:
        d = duty[rid]
        called_back = not d["serving"]
        d["target"], d["alt"], d["serving"] = spot, alt, True
        if called_back:
            print(f"{rid}: called back to relay duty")
        if called_back and d["ready"]:
            run(recall, crew[rid])
        elif d["ready"]:
            run(go, crew[rid])
    for rid, d in duty.items():  # duty bundles that run out soon are renewed
        if d["serving"] and d["ready"] and d.get("until") is not None and d["until"] - relays.now() < RENEW_S and rid not in moved:
            d["until"] = None  # once: go() sets it again
            run(go, crew[rid])
    for spot, alt in plan.dispatch:
        state["dispatching"] += 1
        run(dispatch, spot, alt)
    leaving = state["leaving"]
    for rid in list(leaving):
        if rid not in plan.home:
            del leaving[rid]
    for rid in plan.home:
        leaving[rid] = leaving.get(rid, 0) + 1
        if leaving[rid] >= RELEASE_AFTER:
            del leaving[rid]
            run(send_home, crew[rid])


def distance(drone):
    """The thesis's algorithm: each drone beyond target_dist gets a follower, which may
    get its own (scripts 5.9–5.13)."""
    if drone.id in state["followed"] or drone.state != "active":
        return
    if relays.needs_follower(drone, ground_spot(drone), len(duty), target_dist):
        state["followed"].append(drone.id)
        run(follow, drone)


def reposition(me, spot, alt, bearing, speed):
    if not on_duty(me):
        return
    move(me, to=spot, alt=me.home.alt + alt, yaw=bearing * deg, speed=speed * m / s)


def follow(other):
    # Alternating altitudes (script 5.9), and never the altitude of the relay it follows.
    levels = {"base_alt": base_alt, "alt_diff": alt_diff, "min_separation": min_separation}
    high, low = (relays.duty_altitude(i, list(served.values()), **levels) for i in (0, 1))
    if other.id in duty:
        alt = low if duty[other.id]["alt"] == high else high
    else:
        alt = high if len(duty) % 2 == 0 else low
    me = assign(any_relay)
    crew[me.id] = me
    duty[me.id] = {"target": None, "alt": alt, "serving": True, "ready": False}
    print(f"{me.id}: following {other.id} at {alt:g} m (distance mode, target {relays.metres(target_dist, 'target_dist'):g} m)")
    arm(me)
    takeoff(me, alt * m)
    duty[me.id]["ready"] = True
    current = me.position
    while other.state in ("active", "hold"):
        others = [d for d in list(crew.values()) + list(served.values()) if d.id != me.id]
        spot, speed, bearing, back = relays.follow_step(other, me, ground_spot(other), target_dist, me.home.alt + alt,
                                                        others, min_separation)
        if back:
            break
        if spot.distance(current) > relays.metres(step, "step"):
            current = spot
            run(reposition, me, spot, alt, bearing, speed)
        wait(other)
    state["followed"].remove(other.id)
    send_home(me)


def chain(drone):
    """mode="chain" (relay/chain.py): a probe relay measures the hop that holds, then a
    chain per drone on that hop; the drones' gotos wait at the chain's edge."""
    if not new_round(drone):
        return
    if state.get("duty") is None:
        if not any(d.state in ("active", "hold") for d in served.values()):
            return  # the levels are set above the served drones' flights, once they fly
        # Relays hover above the drones they serve and fly to and from their spots on
        # levels of their own above that (outbound): none crosses a served drone's level.
        state["duty"] = relays.above_flights(list(served.values()), relays.level_gap(min_separation))
    plan = relays.chain(list(served.values()), crew, ground_spot(drone), state["duty"], good_m=good_m,
                        min_separation=min_separation)
    for note in plan.notes:
        print(note)
    for rid, spot, hold in plan.moves:
        run(chain_go, crew[rid], spot, hold)
    for spot, hold, key, launcher in plan.dispatch:
        run(chain_dispatch, key, spot, hold, launcher)
    for rid in plan.home:
        run(chain_home, crew[rid])
    for rid in plan.failed:
        if rid in crew:
            run(chain_failed, crew[rid], "assigned but never took off")
    for rid in list(crew):  # duty bundles that run out soon are renewed where they stand
        until = state["until"].get(rid)
        if until is not None and until - relays.now() < RENEW_S:
            state["until"][rid] = None
            run(chain_go, crew[rid], crew[rid].position, 0)


def levels(relay, alt):
    return relay.home.alt + alt


def outbound(relay):
    """The level a relay flies to and from its spots at, above the duty level: one of its
    own, higher for each relay sent after it. Relays are sent to farther spots later, so
    one coming down to its spot never crosses the level of one flying over it."""
    if relay.id not in state["lanes"]:
        state["lanes"][relay.id] = len(state["lanes"]) + 1
    return state["duty"] + state["lanes"][relay.id] * relays.level_gap(min_separation)


def chain_dispatch(key, spot, hold, launcher):
    relay = assign(launcher)  # from where the plan found its column clear
    # Above every relay still out, also when sent again: its old, lower level had one
    # come down through the level of one flying out over its spot.
    state["lanes"][relay.id] = max([n for r, n in state["lanes"].items() if r in crew], default=0) + 1
    crew[relay.id] = relay
    state["gone"].discard(relay.id)
    relays.chain_joined(key, relay)
    print(f"{relay.id}: relay duty at {state['duty']:g} m ({key})")
    arm(relay)
    chain_go(relay, spot, hold, [steps.takeoff(outbound(relay) * m)])


def chain_go(relay, spot, hold, first=None):
    """Climb to the transit level where it is, fly over the spot, come down to duty;
    a probe (`hold` > 0) comes back to the last proven spot after its window. One bundle
    (from the takeoff on, `first`): the relay's own lost-link failsafe never interrupts it."""
    if relay.id not in crew or relay.id in state["gone"]:
        return  # sent home meanwhile
    duty, up = state["duty"], outbound(relay)
    here = relay.position
    if first is None and hold == 0 and here.distance(spot) <= 3 and abs(here.alt - levels(relay, duty)) <= 2:
        # a renewal where it hovers: no climb to its level and back (it crossed the level of
        # a relay flying by on it)
        plan = [steps.move(to=spot, alt=levels(relay, duty) * m)]
    else:
        plan = (first or []) + [steps.move(to=here, alt=levels(relay, up) * m),
                                steps.move(to=spot, alt=levels(relay, up) * m, speed=10 * m / s),
                                steps.move(to=spot, alt=levels(relay, duty) * m)]
    safe = relays.probe_safe()
    if hold > 0 and safe is not None:
        plan += [steps.wait(hold * s), steps.move(to=spot, alt=levels(relay, up) * m),
                 steps.move(to=safe, alt=levels(relay, up) * m, speed=10 * m / s),
                 steps.move(to=safe, alt=levels(relay, duty) * m)]
    plan.append(steps.wait(CHAIN_DUTY_S * s))
    state["until"][relay.id] = relays.now() + CHAIN_DUTY_S
    record = push(relay, plan, on_link_loss="continue", timeout=(CHAIN_DUTY_S + 300) * s)
    if record.state == "failed" and relay.id in crew and relay.id not in state["gone"]:
        # Its slot is asked for again. Seen: a relay sent home and at once again, armed
        # still after landing, which PX4 then disarmed before its takeoff step (the
        # slot waited for it until the time limit).
        relays.chain_failed(relay.id)
        chain_failed(relay, f"its duty failed at step {record.step + 1} ({record.reason})")


def chain_failed(relay, why):
    """A relay that cannot do its duty: its slot is asked for again (the plan does that);
    it stays assigned a while, so that another drone is sent, and for good once it has
    failed twice (a drone that cannot arm would otherwise be sent again and again)."""
    state["failures"][relay.id] = state["failures"].get(relay.id, 0) + 1
    again = state["failures"][relay.id] < 2
    chain_leave(relay, f"{why}; the plugin sends another relay" + ("" if again else ", and no longer this one"),
                keep_s=FAILED_KEPT_S if again else None)


def chain_home(relay):
    chain_leave(relay, "relay no longer needed, returning")


def chain_leave(relay, why, keep_s=0):
    """Home and revoked; with `keep_s`, revoked that long after landing (None: never,
    the mission keeps it out of the plugin's reach until it ends)."""
    if relay.id in state["gone"]:
        return  # on its way home already
    state["gone"].add(relay.id)
    relays.chain_dropped(relay.id)
    state["until"].pop(relay.id, None)
    print(f"{relay.id}: {why}")
    if relay.state != "ready":  # unless on the ground, disarmed (a relay out of reach flies home too)
        come_down(relay)
    if relay.id in crew:
        del crew[relay.id]
        if keep_s is None:
            return
        if keep_s:
            sleep(keep_s * s)
        revoke(relay)


def come_down(relay):
    """Home on its own transit level, then down where no drone flies below it. (A return
    to launch flies a cone-limited altitude near home, where the relays' levels met:
    two relays going home came within 2.6-3.9 m.)"""
    up = levels(relay, outbound(relay)) * m
    # One bundle: a relay whose chain went home before it flies on without the link.
    push(relay, [steps.move(to=relay.position, alt=up), steps.move(to=relays.landing_spot(relay), alt=up, speed=10 * m / s)],
         on_link_loss="continue", timeout=300 * s)
    waited = 0
    while not relays.clear_below(relay) and waited < LAND_WAIT_S:
        sleep(1 * s)
        waited += 1
    if waited >= LAND_WAIT_S:
        print(f"{relay.id}: a drone stays below it; coming down after {LAND_WAIT_S} s")
    land(relay)


def main(drone):
    if mode not in MODES:
        raise ValueError(f"relay: mode must be one of {', '.join(MODES)}, not {mode!r}")
    if drone.id in crew:
        if mode == "distance":
            distance(drone)  # relays are followed in turn: chains
        return
    if drone.id in state["gone"]:
        return  # a relay going home, or kept out after failing: not a drone to serve
    served[drone.id] = drone
    if mode == "distance":
        distance(drone)
    elif mode == "chain":
        chain(drone)
    else:
        measured(drone)


plugin(id="relay", type=monitoring,
       input={"mode": (str, "chain"), "min_quality": (float, 0.6), "base_alt": (float, 5.0),
              "alt_diff": (float, 5.0), "step": (float, 4.0), "min_separation": (float, 5.0),
              "target_dist": (float, 50.0), "good_m": (float, 60.0), "lost_m": (float, 100.0),
              "ground": (list, [])},
       callback=main,
       doc="Keep the mission's drones connected with relay drones, on measured link quality (mode='distance': the thesis's baseline).")
