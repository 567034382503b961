"""Link quality windows, the lost-link policy and the radio model: pure logic, no loop."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dronefleet.agent.link import LOSS_UNUSABLE, DeliveryWindow, LinkWindow, LostLink, LostLinkPolicy, quality_score
from dronefleet.sim.radio import RadioModel, Spot3, link_losses


def test_window_measures_loss_rtt_and_jitter_over_the_last_probes() -> None:
    w = LinkWindow(4)
    for rtt in (10.0, 30.0, None, 20.0, None):
        w.add(rtt)
    s = w.summary()  # the window holds 30, None, 20, None
    assert s.loss == 0.5
    assert s.rtt_ms == 25.0
    assert s.jitter_ms == 10.0
    assert s.quality == 0.0  # half the probes unanswered: past LOSS_UNUSABLE


def test_quality_falls_with_rtt_and_is_zero_without_answers() -> None:
    assert quality_score(0.0, 10.0) == 1.0
    assert quality_score(0.0, 525.0) == 0.5
    assert quality_score(0.0, 2000.0) == 0.0
    assert quality_score(1.0, None) == 0.0
    empty = LinkWindow()
    assert empty.summary().quality == 0.0 and empty.summary().loss == 1.0


@given(st.floats(0, 1), st.floats(0, 1), st.floats(0, 2000))
def test_quality_falls_as_loss_rises_and_is_half_at_half_the_unusable_loss(a: float, b: float, rtt_ms: float) -> None:
    low, high = sorted((a, b))
    assert quality_score(low, rtt_ms) >= quality_score(high, rtt_ms)
    assert quality_score(LOSS_UNUSABLE / 2, 10.0) == 0.5
    assert quality_score(high, rtt_ms) == 0.0 or high < LOSS_UNUSABLE


@given(st.integers(0, 20))
def test_delivery_loss_is_the_per_packet_loss_of_a_round_trip(echoed: int) -> None:
    """A train's echoes cross the hop twice: delivered share (1 - p)², loss p."""
    w = DeliveryWindow(trains=2)
    outcomes: list[float | None] = [5.0] * echoed + [None] * (20 - echoed)
    w.add(outcomes[:10])
    w.add(outcomes[10:])
    s = w.summary()
    assert s.loss == pytest.approx(1 - math.sqrt(echoed / 20), abs=1e-3)
    assert w.echoed == (echoed > 0)
    assert (s.rtt_ms is None) == (echoed == 0)


def test_lost_link_holds_then_returns_and_reports_on_restore() -> None:
    ll = LostLink(LostLinkPolicy(timeout_s=5, action="hold", return_after_s=30), now=0.0)
    ll.contact(0.0)  # the ground heard at the start: the failsafe is armed
    assert ll.tick(4.9, flying=True) == []
    assert ll.tick(5.0, flying=True) == [("link_lost", None), ("failsafe", "hold")]
    assert ll.tick(20.0, flying=True) == []
    assert ll.tick(35.0, flying=True) == [("failsafe", "return")]
    assert ll.tick(60.0, flying=True) == []
    [(decision, summary)] = ll.contact(61.0)
    assert decision == "link_restored"
    assert summary == "after 61.0 s without the ground; failsafe: hold, return"


def test_a_flapping_link_continues_one_outage() -> None:
    ll = LostLink(LostLinkPolicy(timeout_s=3, action="hold", return_after_s=10), now=0.0)
    ll.contact(0.0)  # the ground heard at the start: the failsafe is armed
    assert ll.tick(3.0, flying=True) == [("link_lost", None), ("failsafe", "hold")]
    assert ll.contact(4.0)[0][0] == "link_restored"  # one probe got through
    assert ll.tick(7.0, flying=True) == [("link_lost", None)]  # lost again: no second hold
    assert ll.tick(13.0, flying=True) == [("failsafe", "return")]  # 10 s after the hold (at the first loss)


def test_steady_contact_closes_the_outage() -> None:
    ll = LostLink(LostLinkPolicy(timeout_s=3, action="land"), now=0.0)
    ll.contact(0.0)  # the ground heard at the start: the failsafe is armed
    assert ll.tick(3.0, flying=True) == [("link_lost", None), ("failsafe", "land")]
    ll.contact(4.0)
    for t in (5.0, 6.0, 7.0):
        ll.contact(t)
        ll.tick(t, flying=True)
    assert ll.tick(9.9, flying=True) == []
    assert ll.tick(10.0, flying=True) == [("link_lost", None), ("failsafe", "land")]  # a new outage acts again


def test_sparse_contact_at_the_edge_of_range_does_not_close_the_outage() -> None:
    """Probes getting through now and then (as at 85 m) are not a steady link: the
    next loss continues the outage, so the hold does not repeat and the return is due
    from the hold (here also the first loss)."""
    ll = LostLink(LostLinkPolicy(timeout_s=3, action="hold", return_after_s=6), now=0.0, steady_gap_s=2.0)
    ll.contact(0.0)  # the ground heard at the start: the failsafe is armed
    assert ll.tick(3.0, flying=True) == [("link_lost", None), ("failsafe", "hold")]
    assert ll.contact(3.2)[0][0] == "link_restored"
    ll.contact(5.5)  # 2.3 s of silence in between
    assert ll.tick(6.2, flying=True) == []  # restored 3 s ago, but not steadily
    assert ll.tick(8.5, flying=True) == [("link_lost", None)]  # lost again: no second hold
    assert ll.tick(9.0, flying=True) == [("failsafe", "return")]  # 6 s after the hold


def test_on_the_ground_the_loss_is_reported_but_nothing_is_done() -> None:
    ll = LostLink(LostLinkPolicy(timeout_s=2, action="return"), now=0.0)
    ll.contact(0.0)  # the ground heard at the start: the failsafe is armed
    assert ll.tick(2.0, flying=False) == [("link_lost", None)]
    assert ll.tick(9.0, flying=False) == []


def test_continue_never_acts() -> None:
    ll = LostLink(LostLinkPolicy(timeout_s=1, action="continue", return_after_s=0), now=0.0)
    ll.contact(0.0)  # the ground heard at the start: the failsafe is armed
    assert ll.tick(100.0, flying=True) == [("link_lost", None)]


def test_without_a_ground_ever_heard_the_failsafe_never_arms() -> None:
    """An agent on a mesh with no ground, commanded directly over Zenoh (SPEC §8)."""
    ll = LostLink(LostLinkPolicy(timeout_s=5, action="hold", return_after_s=30), now=0.0)
    for t in (5.0, 6.0, 40.0, 200.0):
        assert ll.tick(t, flying=t > 5.5) == []
    ll.contact(201.0)  # a ground appears: from now on a loss counts
    assert ll.tick(206.0, flying=True) == [("link_lost", None), ("failsafe", "hold")]


def test_a_loss_on_the_ground_acts_only_once_in_the_air_and_returns_counting_from_then() -> None:
    ll = LostLink(LostLinkPolicy(timeout_s=2, action="hold", return_after_s=30), now=0.0)
    ll.contact(0.0)
    assert ll.tick(2.0, flying=False) == [("link_lost", None)]
    assert ll.tick(50.0, flying=False) == []  # disarmed on the ground: nothing done
    assert ll.tick(60.0, flying=True) == [("failsafe", "hold")]  # flown while lost
    assert ll.tick(89.9, flying=True) == []  # 30 s from the hold, not from the loss
    assert ll.tick(90.0, flying=True) == [("failsafe", "return")]


def test_radio_model_thesis_defaults() -> None:
    radio = RadioModel()
    assert radio.loss(59.9) == 0.0
    assert radio.loss(80.0) == pytest.approx(0.5)
    assert radio.loss(100.0) == 1.0
    assert radio.loss_steps(70.0) == 250
    ground, near, far = Spot3(40.0, -8.0, 10.0), Spot3(40.0003, -8.0, 10.0), Spot3(40.0009, -8.0, 10.0)
    losses = link_losses(radio, {"ground": ground, "a": near, "b": far})
    assert set(losses) == {("a", "b"), ("a", "ground"), ("b", "ground")}
    assert losses[("a", "ground")] == 0  # 33 m
    assert losses[("b", "ground")] == 1000  # 100 m
    assert 0 < losses[("a", "b")] < 1000  # 67 m apart: in the unstable band


def test_radio_config_is_strict() -> None:
    with pytest.raises(msgspec.ValidationError, match="lost_m must be greater"):
        msgspec.convert({"good_m": 80, "lost_m": 60}, RadioModel)
    with pytest.raises(msgspec.ValidationError, match="good_meters"):
        msgspec.convert({"good_meters": 80}, RadioModel)


def test_the_ground_is_silent_after_two_probe_periods_without_contact() -> None:
    """One of the signs that a drone needs links through neighbours (agent/neighbours.py)."""
    ll = LostLink(LostLinkPolicy(timeout_s=3), now=0.0, steady_gap_s=2.0)
    assert not ll.silent(2.0)
    assert ll.silent(2.1)
    ll.contact(2.5)
    assert not ll.silent(4.4)
