"""The relay's separation rules have one home (relay/rules.py, issue 78): each part of
the planner keeps what the rules it is given derive, so a mission asking for 10 m
between drones gets 10 m wherever the planner judges a clearance, not 5 m in the part
that kept a number of its own."""

from __future__ import annotations

import pytest

from dronefleet.mission.script.relaying import Relays
from dronefleet.relay.chain import PROBE, Chains, Worker
from dronefleet.relay.rules import DEFAULT, Separation
from dronefleet.relay.ways import Ways, segment_distance

DUTY = 21.0
WIDE = Separation(10.0)


def test_every_clearance_derives_from_the_separation() -> None:
    assert (DEFAULT.way_m, DEFAULT.around_m, DEFAULT.parked_m, DEFAULT.relays_apart_m, DEFAULT.level_gap_m) == \
        (8.0, 5.5, 6.0, 7.0, 6.0)  # what the planner kept before it had rules
    for rules in (DEFAULT, WIDE, Separation(2.0)):
        s = rules.separation_m
        assert rules.around_m > s and rules.parked_m > s and rules.relays_apart_m > s and rules.way_m > rules.around_m
        assert rules.level_gap_m >= rules.parked_m
    with pytest.raises(ValueError, match="min_separation"):
        Separation(0.0)


@pytest.mark.parametrize(("rules", "cut"), [(DEFAULT, False), (WIDE, True)])
def test_a_workers_leg_keeps_the_way_clearance_of_its_rules(rules: Separation, cut: bool) -> None:
    """Another worker's way 10 m across: clear at 5 m (8 m kept), in the way at 10 m (13)."""
    ways = Ways(rules=rules)
    others = {"d2": (0.0, 0.0, 15.0)}
    ways.clear("d2", (0.0, 0.0, 15.0), (0.0, 100.0, 15.0), {"d1": (-50.0, 50.0, 15.0)}, {"d1", "d2"}, 0.0)
    end, other = ways.clear("d1", (-50.0, 50.0, 15.0), (-10.0, 50.0, 15.0), others, {"d1", "d2"}, 1.0)
    assert (other == "d2") is cut, (end, other)
    assert segment_distance((-50.0, 50.0, 15.0), end, (0.0, 0.0, 15.0), (0.0, 100.0, 15.0)) >= rules.way_m - 0.1


@pytest.mark.parametrize(("rules", "launches"), [(DEFAULT, True), (WIDE, False)])
def test_a_relay_climbs_only_from_a_spot_its_rules_call_clear(rules: Separation, launches: bool) -> None:
    """One spare 8 m across from where a worker waits for the probe: clear of it at 5 m
    (6 m kept), not at 10 (11)."""
    worker = Worker("d1", (0.0, 5.0), 15.0, (0.0, 200.0))
    spare = (8.0, 5.0)
    out = Chains(DUTY, first_trial=60.0, rules=rules).plan(0.0, [worker], {}, spare=1, others=[(spare, 0.0)],
                                                          spares=[spare])
    assert ([key for key, _, _, _ in out.dispatch] == [PROBE]) is launches, out.dispatch


def test_the_plugins_levels_and_the_planners_rules_come_from_its_min_separation() -> None:
    relays = Relays()
    assert relays.level_gap(5.0) == DEFAULT.level_gap_m
    assert relays.level_gap(10.0) == WIDE.level_gap_m and relays.separation(10.0) == WIDE
    with pytest.raises(ValueError, match="relay: min_separation"):
        relays.separation(0.0)
