"""Shared fixtures: a real Zenoh router on a unique 127.0.0.1 port, client sessions,
and agent subprocesses that are always stopped."""

from __future__ import annotations

import fcntl
import itertools
import os
import resource
import signal
import time
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from tests.harness import AgentProcess, GroundFleet, Operator, open_ground_router, stop_all
from tests.ports import free_port

# Radio tests at once on this host (`radio_slot` below), each a
# ground, a `fleet sim` and an agent per drone.
# With four at once beside the rest of `make test` on two cores, every drone of one run
# lost the ground together for ~10 s, twice, and a command to a drone 55 m out went
# unanswered for 3 s (full-suite runs of 2026-11-23, before the mesh fix of issue 30);
# each passes alone. Two at once held in 15 fresh-clone runs (5 beside CPU burners).
# Three, with eight workers, saturated both cores from the second minute on and a
# radio run went void (its ground stand-in's loop blocked 0.5 s): 2026-11-24.
RADIO_SLOTS = 2
SLOT_WAIT_S = 240  # how long a radio test waits for one of the host's radio slots


def pytest_configure() -> None:
    """Tests stop `fleet` processes with SIGINT, as an operator's Ctrl-C does. A run
    started in the background by a non-interactive shell (`make test &` in a script)
    inherits SIGINT ignored (POSIX), Python keeps an inherited ignore, and so would every
    process a test starts: none would stop. Take Ctrl-C back, for us and our children."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


LOADGROUP_BROKEN = pytest.StashKey[str]()


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A grouped test fails, saying why, when its group was not kept together; a radio
    test fails outside the radio groups (tests/radio/), one per slot."""
    broken = item.config.stash.get(LOADGROUP_BROKEN, None)
    group = item.get_closest_marker("xdist_group")
    if broken and group:
        pytest.fail(broken)
    if "radio_slot" in getattr(item, "fixturenames", ()):
        groups = {f"radio-{chr(ord('a') + i)}" for i in range(RADIO_SLOTS)}
        if group is None or group.args[0] not in groups:
            pytest.fail(f"a radio test belongs to one of the groups {sorted(groups)} (one per radio slot)")


SPACERS = 3  # short tests after each long one (pytest_collection_modifyitems)


@pytest.hookimpl(trylast=True)  # after pytest-xdist has suffixed the grouped tests' ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Groups, then a few short tests per worker, then the rest longest first (the `slow`
    marker's estimate), real-time and fast-time tests in turns, each followed by short
    tests.

    `make test` runs xdist with `--dist loadgroup`, which hands out work units (one test,
    or a group: the Chromium tests, each radio slot's tests, the modules that share a
    fleet) with the groups first (the most tests first), then in collection order: one
    per worker at first, a second to each, then one each time a worker is down to two
    tests. So the long real-time tests start early, and short ones sit between two long
    ones. The order is the same on every worker (a stable sort), as xdist requires."""
    def seconds(item: pytest.Item) -> float:
        marker = item.get_closest_marker("slow")
        return float(marker.args[0]) if marker is not None else 0.0

    if getattr(config.option, "loadgroup", False):
        lost = [i.nodeid for i in items if i.get_closest_marker("xdist_group") and "@" not in i.nodeid]
        if lost:  # pytest 9.2 with xdist 3.8 (pytest-dev/pytest-xdist#1386): groups spread over workers
            config.stash[LOADGROUP_BROKEN] = (
                f"--dist loadgroup is not grouping {lost[0]} (pytest {pytest.__version__}: see "
                "pytest-dev/pytest-xdist#1386; requirements.lock pins a pytest that groups)")
    # Grouped tests go out first whatever their place, in collection order: a group's
    # modules one after the other, as their module-scoped fleets expect.
    grouped = [i for i in items if i.get_closest_marker("xdist_group")]
    single = [i for i in items if not i.get_closest_marker("xdist_group")]
    # A long test that starts processes mostly waits on real time (drones flying); a long
    # pure one (fast time) is all CPU. Taken in turns, the CPU-bound ones fill the cores
    # while the others wait: longest first, the two kinds one after the other.
    long = sorted((i for i in single if seconds(i)), key=seconds, reverse=True)
    real = [i for i in long if i.get_closest_marker("integration")]
    pure = [i for i in long if not i.get_closest_marker("integration")]
    long = [i for pair in itertools.zip_longest(real, pure) for i in pair if i is not None]
    # Three short tests after each long one: a worker holds its running test and one more
    # (xdist hands it another when it is down to two), so a long test drawn right after
    # another waited for it on the same worker while other workers were free (a 50-s
    # flight contract started at 178 s). The short tests that start processes go first,
    # the pure ones last: they fill the end in a few CPU-seconds, where tests that start
    # processes would compete for both cores with the last long tests.
    short = sorted((i for i in single if not seconds(i)), key=lambda i: i.get_closest_marker("integration") is None)
    # Two short tests per worker right after the groups: xdist hands each worker a second
    # unit at the start, and a worker that drew a group (the radio lanes run 215-230 s)
    # holds that one until its group ends. A 53-s flight contract drawn there started at
    # 214 s and ended the run 40 s after every other worker.
    workers = getattr(config.option, "numprocesses", None)
    lead = 2 * workers if isinstance(workers, int) and grouped else 0
    order: list[pytest.Item] = short[:lead]
    short = short[lead:]
    for n, item in enumerate(long):
        order += [item, *short[SPACERS * n:SPACERS * (n + 1)]]
    items[:] = grouped + order + short[SPACERS * len(long):]


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """With FLEET_TEST_TIMELINE=FILE, each phase of each test appends a line to FILE:
    worker, phase, start and stop (epoch seconds), test id; `python -m tests.timeline
    FILE` draws the schedule (which worker ran what when, where the run waited)."""
    if getattr(report, "node", None) is None:  # not the copy pytest-xdist's controller gets
        _timeline(f"{report.when} {report.start:.3f} {report.stop:.3f} {report.nodeid}")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    """With FLEET_TEST_TIMELINE, also the CPU seconds each test cost: this worker's and
    its reaped children's (the `fleet` processes it started and stopped)."""
    if not os.environ.get("FLEET_TEST_TIMELINE"):
        return (yield)
    before = _cpu_seconds()
    result = yield
    _timeline(f"cpu {_cpu_seconds() - before:.3f} 0 {item.nodeid}")
    return result


def _timeline(line: str) -> None:
    path = os.environ.get("FLEET_TEST_TIMELINE")
    if path:
        with open(path, "a", encoding="utf-8") as out:
            out.write(f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')} {line}\n")


def _cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


@pytest.fixture(autouse=True, scope="session")
def _agent_state_outside_home(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Agents started by tests (and by the `fleet` processes they start) keep their
    bundle records under the test run's temporary directory, never in ~/.local/state."""
    before = os.environ.get("XDG_STATE_HOME")
    os.environ["XDG_STATE_HOME"] = str(tmp_path_factory.mktemp("state"))
    yield
    if before is None:
        os.environ.pop("XDG_STATE_HOME", None)
    else:
        os.environ["XDG_STATE_HOME"] = before


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
async def router(endpoint: str) -> AsyncIterator[ZenohBus]:
    bus = await open_ground_router(endpoint)
    yield bus
    await bus.close()


@pytest.fixture
async def client(router: ZenohBus, endpoint: str) -> AsyncIterator[ZenohBus]:
    bus = await ZenohBus.open("client", connect=[endpoint])
    yield bus
    await bus.close()


@pytest.fixture
def agents(endpoint: str, tmp_path: Path) -> Iterator[Callable[..., AgentProcess]]:
    started: list[AgentProcess] = []

    def start(drone_id: str, **kwargs: Any) -> AgentProcess:
        started.append(AgentProcess(drone_id, endpoint, tmp_path, **kwargs))
        return started[-1]

    yield start
    stop_all(started)


@pytest.fixture
def operator(client: ZenohBus) -> Callable[[str], Operator]:
    return lambda drone_id: Operator(client, drone_id)


@pytest.fixture
async def http(fleet: GroundFleet) -> AsyncIterator[httpx.AsyncClient]:
    """A client of the API of the module's `fleet` (a GroundFleet fixture), per test."""
    async with fleet.client() as client:
        yield client


@pytest.fixture
def radio_slot() -> Iterator[None]:
    """One of RADIO_SLOTS host-wide slots (a lock file each), held while the test runs."""
    deadline = time.monotonic() + SLOT_WAIT_S
    while True:
        for i in range(RADIO_SLOTS):
            fd = os.open(f"/tmp/fleet-test-radio-slot-{i}.lock", os.O_CREAT | os.O_RDWR, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            try:
                yield
            finally:
                os.close(fd)  # releases the lock
            return
        if time.monotonic() > deadline:
            pytest.fail(f"no radio slot free after {SLOT_WAIT_S} s")
        time.sleep(0.2)  # polling a lock held by another test's run
