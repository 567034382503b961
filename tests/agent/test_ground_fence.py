"""SPEC §14 fencing at the agent (agent/ground_fence.py), as properties over random
sequences of grounds speaking with random epochs."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from dronefleet.agent.ground_fence import GroundFence

GROUNDS = ["alpha", "bravo", "charlie"]
# Each event: a command from a ground at an epoch, or its announcement that it is active.
events = st.lists(st.tuples(st.sampled_from(["command", "active"]), st.sampled_from(GROUNDS), st.integers(1, 5)),
                  max_size=60)


@given(events)
def test_no_epoch_is_obeyed_from_two_grounds_and_obeyed_epochs_never_go_back(seen: list[tuple[str, str, int]]) -> None:
    fence, obeyed, holders = GroundFence(), [], dict[int, str]()
    for kind, ground, epoch in seen:
        if kind == "active":
            fence.heard(epoch, ground)
        elif fence.admits(epoch, ground):
            obeyed.append(epoch)
            assert holders.setdefault(epoch, ground) == ground, (epoch, holders, ground)
    assert obeyed == sorted(obeyed), obeyed


@given(events, st.sampled_from(GROUNDS))
def test_a_ground_above_every_epoch_heard_is_obeyed(seen: list[tuple[str, str, int]], ground: str) -> None:
    """Liveness: the ground told the epoch in use (stale_ground) takes one above it, and is obeyed."""
    fence = GroundFence()
    for kind, g, epoch in seen:
        fence.heard(epoch, g) if kind == "active" else fence.admits(epoch, g)
    assert fence.admits(fence.epoch + 1, ground)
    assert fence.admits(0, ground)  # a direct client on the mesh is never fenced


def test_a_restarted_ground_that_took_the_epoch_in_use_is_refused_until_it_takes_one_above() -> None:
    fence = GroundFence()
    assert fence.admits(1, "alpha")
    fence.heard(2, "bravo")  # alpha died; bravo took over
    assert fence.admits(2, "bravo")
    assert not fence.admits(2, "alpha")  # alpha back alone, its data said 1: it took 2 too
    assert not fence.admits(1, "alpha")
    assert fence.admits(3, "alpha") and not fence.admits(2, "bravo")
