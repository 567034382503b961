"""Drone assignment as pure logic: thesis priority order, fewest sensors, nearest, battery ties."""

from __future__ import annotations

import pytest

from dronefleet.mission.lifecycle.assignment import (
    AllOf,
    AnyDrone,
    AnyRelay,
    ById,
    ByKind,
    ByRole,
    BySensors,
    Candidate,
    Near,
    Unfulfilled,
    assign_many,
    choose,
    replaceable,
    replacement,
)

FIELD = (40.633490, -8.660815)
FREE = [
    Candidate("plain", battery=0.9, lat=40.6335, lon=-8.6608),
    Candidate("thermal", frozenset({"temperature"}), battery=0.5, lat=40.6345, lon=-8.6608),
    Candidate("survey", frozenset({"temperature", "camera"}), battery=0.99, lat=40.6300, lon=-8.6608, kind="fixed_wing"),
    Candidate("weak", battery=0.2, lat=40.6336, lon=-8.6608),
]


@pytest.mark.parametrize(
    ("request_", "expected"),
    [
        (ById("weak"), "weak"),
        (BySensors(frozenset({"temperature"})), "thermal"),  # fewest sensors that fit, not most battery
        (BySensors(frozenset({"camera"})), "survey"),
        (AnyDrone(), "plain"),  # no sensors, then the most battery
        (Near(40.6346, -8.6608), "thermal"),
        (ByKind("fixed_wing"), "survey"),
    ],
)
def test_one_request_picks_the_thesis_choice(request_, expected: str) -> None:
    assert choose(request_, FREE).drone_id == expected


def test_battery_breaks_ties() -> None:
    twins = [Candidate("a", battery=0.4), Candidate("b", battery=0.7), Candidate("c", battery=0.7)]
    assert choose(AnyDrone(), twins).drone_id == "b"  # then the id, for determinism


def test_several_at_once_are_served_in_priority_order_not_in_the_order_asked() -> None:
    # Asked in the worst order: `any` first would take a drone a later request needs.
    only_two = [Candidate("thermal", frozenset({"temperature"}), battery=0.1), Candidate("plain", battery=0.2)]
    assert assign_many([AnyDrone(), BySensors(frozenset({"temperature"}))], only_two) == ["plain", "thermal"]
    ids = assign_many([AnyDrone(), ById("plain"), Near(40.6336, -8.6608)], FREE)
    assert ids[1] == "plain" and ids[2] == "weak" and ids[0] == "thermal"


def test_more_demanding_sensor_requests_pick_first() -> None:
    pool = [Candidate("both", frozenset({"temperature", "camera"})), Candidate("temp", frozenset({"temperature"}))]
    got = assign_many([BySensors(frozenset({"temperature"})), BySensors(frozenset({"temperature", "camera"}))], pool)
    assert got == ["temp", "both"]


def test_unmet_requests_fail_all_or_nothing_naming_the_request() -> None:
    with pytest.raises(Unfulfilled, match="cannot assign a drone with lidar"):
        assign_many([AnyDrone(), BySensors(frozenset({"lidar"}))], FREE)
    with pytest.raises(Unfulfilled, match="drone 'ghost'"):
        choose(ById("ghost"), FREE)
    with pytest.raises(Unfulfilled, match="no free drone"):
        assign_many([AnyDrone()] * 5, FREE)


def test_replacement_is_the_nearest_free_drone_and_id_or_sensor_assignments_are_irreplaceable() -> None:
    assert replacement(40.6301, -8.6608, FREE) == "survey"
    assert replacement(40.6301, -8.6608, []) is None
    assert not replaceable(ById("x")) and not replaceable(BySensors(frozenset({"temperature"})))
    assert replaceable(AnyDrone()) and replaceable(Near(*FIELD)) and replaceable(ByKind("quad"))


def test_only_drones_that_may_relay_serve_any_relay_and_any_drone_keeps_them_free() -> None:
    """On a secured mesh only drones issued `--role relay` carry others' traffic (SPEC §9):
    `any_relay` picks among them; `any_drone` takes one that may not relay first."""
    free = [Candidate("plain", battery=0.5, relay=False), Candidate("relay_low", battery=0.4, relay=True),
            Candidate("strong", battery=0.7, relay=False), Candidate("relay_high", battery=0.8, relay=True)]
    assert choose(AnyRelay(), free).drone_id == "relay_high"
    assert choose(AnyDrone(), free).drone_id == "strong"  # less battery than "relay_high", but may not relay
    assert choose(AnyDrone(), [free[1], free[3]]).drone_id == "relay_high"  # when only relays are free, any of them
    assert assign_many([AnyDrone(), AnyRelay()], free[:2]) == ["plain", "relay_low"]  # the relay request picks first
    with pytest.raises(Unfulfilled, match="cannot assign a drone that may relay .*--role relay.*: no free drone fits"):
        choose(AnyRelay(), [c for c in free if not c.relay])


def test_keywords_together_describe_one_drone_the_nearest_that_fits_them_all() -> None:
    """assign(sensor="gas", role="survey", near=pos): one drone meeting every part."""
    free = [
        Candidate("near_plain", battery=0.9, lat=40.6346, lon=-8.6608),  # nearest, no gas
        Candidate("far_gas", frozenset({"gas"}), battery=0.9, lat=40.6300, lon=-8.6608),
        Candidate("mid_gas", frozenset({"gas"}), battery=0.1, lat=40.6340, lon=-8.6608),
        Candidate("aux_gas", frozenset({"gas"}), battery=1.0, lat=40.6346, lon=-8.6609, roles=frozenset({"auxiliary"})),
    ]
    gas_near = AllOf((BySensors(frozenset({"gas"})), ByRole("survey"), Near(40.6346, -8.6608)))
    assert choose(gas_near, free).drone_id == "mid_gas"  # the nearest fitting, not the nearest, nor the auxiliary
    assert not replaceable(gas_near)  # a sensor was asked for
    assert replaceable(AllOf((ByKind("x"), Near(40.0, -8.0))))
    # an auxiliary drone is taken only when a part names its role
    aux = AllOf((ByRole("auxiliary"), Near(40.6346, -8.6608)))
    assert choose(aux, free).drone_id == "aux_gas"
    with pytest.raises(Unfulfilled, match="a drone with camera and the drone nearest"):
        choose(AllOf((BySensors(frozenset({"camera"})), Near(40.6346, -8.6608))), free)
    # served with the rank of its most demanding part: before a plain proximity request
    assert assign_many([Near(40.6340, -8.6608), gas_near], free) == ["near_plain", "mid_gas"]
