"""What an agent sends again when the ground answers after a gap (agent/status_resend.py),
as properties over random runs of publications and probe answers."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from dronefleet.agent.status_resend import GAP_PERIODS, KEPT, StatusResend
from dronefleet.schemas.bundles import BundleStatus
from dronefleet.schemas.status import CommandStatus, SystemStatus

PERIOD_MS = 1000


def command(n: int, at_ms: int) -> CommandStatus:
    return CommandStatus(drone_id="d1", timestamp=at_ms, command_id=f"c{n}", command="arm", state="start")


def bundle(n: int, at_ms: int) -> BundleStatus:
    return BundleStatus(drone_id="d1", timestamp=at_ms, bundle_id=f"b{n}", step=0, state="start")


def system(at_ms: int) -> SystemStatus:
    return SystemStatus(drone_id="d1", timestamp=at_ms, component="system", state="connect")


# A run: steps of (ms later, what happens): a command, bundle or system status published,
# or an answer from the ground.
steps = st.lists(st.tuples(st.integers(0, 4 * PERIOD_MS), st.sampled_from(["command", "bundle", "system", "contact"])),
                 max_size=80)


Published = CommandStatus | SystemStatus | BundleStatus
Contact = tuple[int, int | None, list[Published], list[CommandStatus | BundleStatus]]


def play(run: list[tuple[int, str]]) -> list[Contact]:
    """Each contact: (when, the previous contact, what was published until then, what was repeated)."""
    policy = StatusResend(PERIOD_MS)
    now: int = 0
    last: int | None = None
    published: list[Published] = []
    contacts: list[Contact] = []
    for n, (later, what) in enumerate(run):
        now += later
        if what == "contact":
            repeated = [s for r in policy.contact(now).repeats for s in r.statuses]
            contacts.append((now, last, list(published), repeated))
            last = now
            continue
        status: Published = command(n, now) if what == "command" else bundle(n, now) if what == "bundle" else system(now)
        policy.published(status)
        published.append(status)
    return contacts


@given(steps)
def test_the_first_answer_repeats_every_command_and_bundle_status_published_before_it(run: list[tuple[int, str]]) -> None:
    contacts = play(run)
    if contacts:
        _, _, before, repeated = contacts[0]
        wanted = [s for s in before if not isinstance(s, SystemStatus)][:KEPT]
        assert repeated == wanted


@given(steps)
def test_a_gap_repeats_every_command_status_it_may_have_swallowed(run: list[tuple[int, str]]) -> None:
    """A command status published from a period before the ground went silent up to its
    answer is repeated at that answer (within the last KEPT commands)."""
    for now, last, published, repeated in play(run)[1:]:
        assert last is not None
        if now - last > GAP_PERIODS * PERIOD_MS:
            commands = [s for s in published if isinstance(s, CommandStatus)][-KEPT:]
            for status in commands:
                if status.timestamp >= last - PERIOD_MS:
                    assert status in repeated


@given(steps)
def test_a_link_that_holds_repeats_nothing(run: list[tuple[int, str]]) -> None:
    contacts = play(run)
    steady = True
    for now, last, _, repeated in contacts[1:]:
        assert last is not None
        steady = steady and now - last <= GAP_PERIODS * PERIOD_MS
        if steady:
            assert repeated == []


def test_repeats_go_on_until_the_link_has_held_for_steady_probes() -> None:
    """A repeat can go down with a link that closes again at once: after a second gap
    soon after the first, the first gap's statuses are repeated again."""
    policy = StatusResend(PERIOD_MS, steady_probes=5)
    policy.contact(0)
    early = command(1, 500)
    policy.published(early)
    assert [r.statuses for r in policy.contact(5000).repeats] == [[early]]  # the gap 0 → 5 s
    policy.contact(6000)
    assert [r.statuses for r in policy.contact(9000).repeats] == [[early]]  # a second gap before the link held
    for at in range(10_000, 16_000, 1000):
        policy.contact(at)
    late = command(2, 16_500)
    policy.published(late)
    assert [r.statuses for r in policy.contact(20_000).repeats] == [[late]]  # held 5 periods: the first is heard
