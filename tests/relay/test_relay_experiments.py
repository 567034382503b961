"""Issue 15's relay experiments in fast time, judged from result.json
(fleet/relay_experiments.py; the README's table comes from bench/relay_experiments.py).

Thesis script 6.2: a drone maps an area 80-135 m from the laptop on the default radio
(messages thin out from 60 m, none get through from 100 m). Two ways: two drones hold
110 m out, 60° apart.
"""

from __future__ import annotations

import math

import pytest

from dronefleet import relay_experiments as rx

MIN_SEPARATION_M = 5.0  # geofence.min_separation_m unset


@pytest.mark.slow(8)
async def test_script_6_2_keeps_the_mapping_drone_heard_with_relays_and_loses_it_without() -> None:
    none = rx.metrics(await rx.run(rx.MAPPING["none"]), ("drone01",))
    distance = rx.metrics(await rx.run(rx.MAPPING["distance"]), ("drone01",))
    measured_result = await rx.run(rx.MAPPING["measured"])
    measured = rx.metrics(measured_result, ("drone01",))

    assert none.status == "failed (link_lost)" and none.longest_gap_s > 10, none  # out of reach, for good
    assert measured.status == "finished (success)", measured
    assert measured.longest_gap_s < 3.0 and measured.connected > 0.95, measured
    assert 1 <= measured.relays <= distance.relays, (measured, distance)
    # The thesis's baseline is not held to finishing: on the mesh the agents build (a
    # drone links through neighbours only while it needs them, ADR 0003) its relay 50 m
    # behind the mapping drone holds its own 40 %-loss link to the laptop, and the mapping
    # drone was lost 29 s (link_lost); with every pair of drones linked, it had finished.
    assert distance.relays >= 1, distance
    for m in (measured, distance):
        assert m.separation_m >= MIN_SEPARATION_M, m
    # every relay was released: none is still assigned at the end, all back on the ground
    assert any("relay no longer needed" in line["message"] for line in measured_result["log"])
    for relay in rx.relays_flown(measured_result, ("drone01",)):
        assert measured_result["drones"][relay]["flown"][-1]["rel_alt"] < 1.0, relay


@pytest.mark.slow(16)
async def test_two_drones_in_two_directions_need_fewer_relays_than_one_chain_per_drone() -> None:
    served = ("drone01", "drone02")
    distance = rx.metrics(await rx.run(rx.TWO_WAYS["distance"]), served)
    measured = rx.metrics(await rx.run(rx.TWO_WAYS["measured"]), served)
    assert measured.status == "finished (success)", measured
    # The baseline finishes too: gotos its drones' lost-link hold cut short are sent again.
    assert distance.status == "finished (success)", distance
    assert measured.relays < distance.relays, (measured, distance)
    assert measured.connected >= distance.connected - 0.02, (measured, distance)  # the same connectivity, or better
    assert measured.longest_gap_s < 5.0, measured  # under the agents' lost-link timeout
    # Measured mode keeps its relays apart here. The thesis's baseline does not promise
    # it: its relays of two chains follow within 5 m of each other and climb through
    # each other's level on their way home (4.8 m in this world since the radio's random
    # streams became per link; the corpus of issue 32 counts such near misses in both modes).
    assert measured.separation_m >= MIN_SEPARATION_M, measured


def test_metrics_read_gaps_connectivity_and_separation_from_a_result() -> None:
    def sample(t: float, north_m: float = 0.0, alt: float = 10.0) -> dict[str, object]:
        return {"t_s": t, "lat": 40.0 + north_m / 111_195, "lon": -8.0, "rel_alt": alt, "battery": 1.0 - t / 100}

    result = {
        "t0_ms": 0, "mission": {"status": "finished", "cause": "success", "start": 0, "end": 10_000},
        "drones": {
            "d1": {"samples": [sample(t) for t in (0, 1, 2, 6, 7, 8, 9, 10)]},  # a 4 s gap
            "r1": {"samples": [sample(t, 3.0, 14.0) for t in range(11)]},  # 5 m away: 3 m north, 4 m up
        },
    }
    m = rx.metrics(result, ("d1",))
    assert m.longest_gap_s == 4.0 and m.connected == pytest.approx(0.6) and m.relays == 1
    assert m.separation_m == pytest.approx(5.0, abs=0.01) and m.battery == pytest.approx(0.2)
    assert not math.isinf(m.separation_m)
