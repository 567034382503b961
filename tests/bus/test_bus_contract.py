"""One contract, two adapters: the in-memory bus must behave like real Zenoh.

The Zenoh runs use a real router session and real client sessions on 127.0.0.1
with a unique port and scouting off.
"""

from __future__ import annotations

import asyncio
import operator
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from functools import partial

import pytest

from dronefleet.bus.clock import SystemClock, VirtualClock
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.bus.port import Bus, QueryRefused, QueryTimeout, Unreachable, echo
from dronefleet.bus.redeclarable import OVERLAP_S, Redeclarable
from dronefleet.bus.zenoh_bus import ZenohBus
from tests.ports import free_port
from tests.waiting import Collector, until

MeshFactory = Callable[[], Awaitable[Bus]]


@pytest.fixture(params=["memory", pytest.param("zenoh", marks=pytest.mark.integration)])
async def mesh(request: pytest.FixtureRequest) -> AsyncIterator[MeshFactory]:
    opened: list[Bus] = []
    if request.param == "memory":
        net = MemoryNetwork()

        async def factory() -> Bus:
            opened.append(MemoryBus(net))
            return opened[-1]
    else:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        opened.append(await ZenohBus.open("router", listen=[endpoint]))

        async def factory() -> Bus:
            opened.append(await ZenohBus.open("client", connect=[endpoint]))
            return opened[-1]
    yield factory
    for bus in reversed(opened):
        await bus.close()


async def publish_until_seen(bus: Bus, key: str, seen: Collector, timeout_s: float = 5.0) -> None:
    """A subscription declared elsewhere takes a moment to reach the router: probe until it does."""
    deadline = time.monotonic() + timeout_s
    while not any(s.payload == b"probe" for s in seen.items):
        assert time.monotonic() < deadline, f"subscription for {key} never became reachable"
        bus.publish(key, b"probe")
        try:
            await seen.wait_for(lambda s: s.payload == b"probe", timeout_s=0.1)
        except AssertionError:
            pass


async def serve_reachably(server: Bus, client: Bus, key: str, handler) -> None:
    """Declare a queryable and wait (deadline 5 s) until the client's queries reach it;
    the handler must answer the payload b"warm"."""
    server.serve(key, handler)
    await reachable(client, key)


async def reachable(client: Bus, key: str) -> None:
    """Wait (deadline 5 s) until the client's queries on `key` reach a queryable that
    answers the payload b"warm"."""
    deadline = time.monotonic() + 5
    while True:
        try:
            await client.query(key, b"warm", timeout_s=1)
            return
        except Unreachable:
            assert time.monotonic() < deadline, f"queryable {key} never became reachable"
            await asyncio.sleep(0.05)


async def test_wildcard_subscriptions_route_by_key(mesh: MeshFactory) -> None:
    pub, sub = await mesh(), await mesh()
    one_kind, one_drone = Collector(), Collector()
    sub.subscribe("drone/*/telem", one_kind)
    sub.subscribe("drone/d1/**", one_drone)
    await publish_until_seen(pub, "drone/d1/telem", one_kind)
    await publish_until_seen(pub, "drone/d1/telem", one_drone)
    pub.publish("drone/d1/status", b"s1")
    pub.publish("drone/d2/telem", b"t2")
    pub.publish("drone/d1/telem", b"t1")
    await one_kind.wait_for(lambda s: s.payload == b"t1")
    await one_drone.wait_for(lambda s: s.payload == b"t1")
    assert [s.key for s in one_kind.items if s.payload != b"probe"] == ["drone/d2/telem", "drone/d1/telem"]
    assert [s.payload for s in one_drone.items if s.payload != b"probe"] == [b"s1", b"t1"]


async def test_reliable_samples_arrive_in_order_without_loss(mesh: MeshFactory) -> None:
    pub, sub = await mesh(), await mesh()
    got = Collector()
    sub.subscribe("drone/d1/status", got, maxsize=5000)
    await publish_until_seen(pub, "drone/d1/status", got)
    for i in range(2000):
        pub.publish("drone/d1/status", str(i).encode())
    await got.wait_for(lambda s: s.payload == b"1999", timeout_s=10)
    numbers = [int(s.payload) for s in got.items if s.payload != b"probe"]
    assert numbers == list(range(2000))


async def test_latest_only_subscription_keeps_the_newest(mesh: MeshFactory) -> None:
    pub, sub = await mesh(), await mesh()
    got = Collector()
    sub.subscribe("drone/d1/telem", got, latest_only=True, maxsize=3)
    await publish_until_seen(pub, "drone/d1/telem", got)
    # A burst larger than the inbox: whatever is dropped, the newest must arrive last.
    for i in range(50):
        pub.publish("drone/d1/telem", str(i).encode(), reliable=False)
    await got.wait_for(lambda s: s.payload == b"49", timeout_s=5)
    assert int(got.items[-1].payload) == 49


async def test_query_is_answered_by_the_matching_queryable(mesh: MeshFactory) -> None:
    server, client = await mesh(), await mesh()

    async def echo(key: str, payload: bytes) -> bytes:
        return key.encode() + b"|" + payload

    await serve_reachably(server, client, "drone/d1/cmd", echo)
    reply = await client.query("drone/d1/cmd", b"arm", timeout_s=2)
    assert reply == b"drone/d1/cmd|arm"


async def test_a_queryable_declared_afresh_answers_every_query_around_it_once(mesh: MeshFactory) -> None:
    """The agent's command queryable after a contact gap (bus/redeclarable.py):
    queries that reached the old declaration are answered after it is gone, queries
    sent after reach the new one (the other form, `K/**`), and each runs once."""
    server, client = await mesh(), await mesh()
    runs: list[bytes] = []
    held = asyncio.Event()

    async def handler(key: str, payload: bytes) -> bytes:
        runs.append(payload)
        if payload.startswith(b"held"):
            await held.wait()
        return key.encode() + b"|" + payload

    served = Redeclarable(server, "drone/d1/cmd", handler, SystemClock())
    await reachable(client, "drone/d1/cmd")
    for round_ in range(3):
        query = b"held%d" % round_
        pending = asyncio.ensure_future(client.query("drone/d1/cmd", query, timeout_s=5))
        await until(partial(operator.contains, runs, query), 5, "the held query at the handler")
        served.refresh()
        held.set()
        assert await pending == b"drone/d1/cmd|held%d" % round_
        held.clear()
        assert await client.query("drone/d1/cmd", b"after%d" % round_, timeout_s=2) == b"drone/d1/cmd|after%d" % round_
    assert served.form == "drone/d1/cmd/**" and served.refreshes == 3
    mine = [r for r in runs if r != b"warm"]
    assert sorted(mine) == sorted({*mine}), mine  # none ran twice
    served.close()


async def test_a_query_reaching_both_declarations_runs_once() -> None:
    """Just after a refresh a query can reach both forms: the second gets the first's
    answer; an error is not kept, so a retry runs again. Later the same bytes run
    again (the handler refuses a replayed command as one, SPEC §9)."""
    runs: list[bytes] = []
    gate = asyncio.Event()

    async def handler(key: str, payload: bytes) -> bytes:
        runs.append(payload)
        await gate.wait()
        if payload == b"bad":
            raise ValueError("boom")
        return payload

    clock = VirtualClock()
    served = Redeclarable(MemoryBus(MemoryNetwork()), "drone/d1/cmd", handler, clock)
    served.refresh()
    twice = [asyncio.ensure_future(served._answer("drone/d1/cmd", b"arm")) for _ in range(2)]
    bad = [asyncio.ensure_future(served._answer("drone/d1/cmd", b"bad")) for _ in range(2)]
    await until(lambda: len(runs) == 2, 5, "the handler to start")
    gate.set()
    assert await asyncio.gather(*twice) == [b"arm", b"arm"]
    for outcome in await asyncio.gather(*bad, return_exceptions=True):
        assert isinstance(outcome, ValueError)
    with pytest.raises(ValueError):
        await served._answer("drone/d1/cmd", b"bad")
    assert runs == [b"arm", b"bad", b"bad"]
    await clock.advance(OVERLAP_S + 0.1)
    assert await served._answer("drone/d1/cmd", b"arm") == b"arm"
    assert runs == [b"arm", b"bad", b"bad", b"arm"]


@pytest.mark.integration
async def test_a_reply_says_whether_it_came_over_one_link() -> None:
    """query_linked (the agent's probes, agent/prober.py): the router's own queryable is
    one link from its client; another client's is two, through the router."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = await ZenohBus.open("router", listen=[endpoint])
    near, far = await ZenohBus.open("client", connect=[endpoint]), await ZenohBus.open("client", connect=[endpoint])
    try:
        async def echo(key: str, payload: bytes) -> bytes:
            return payload

        await serve_reachably(router, near, "ground/ping", echo)
        await serve_reachably(far, near, "drone/far/ping", echo)
        assert await near.query_linked("ground/ping", b"p") == (b"p", True)
        assert await near.query_linked("drone/far/ping", b"p") == (b"p", False)
    finally:
        for bus in (far, near, router):
            await bus.close()


@pytest.mark.integration
async def test_a_link_closing_is_told_to_the_session_at_its_end() -> None:
    """watch_links (the agent's telemetry at once after a reroute, agent/runtime.py):
    a router whose link to another closes hears of it; a closed watch hears nothing."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ground = await ZenohBus.open("router", listen=[endpoint])
    # A listener of its own: a router's default is tcp/[::]:7447, which another test may hold.
    drone = await ZenohBus.open("router", connect=[endpoint], listen=[f"tcp/127.0.0.1:{free_port()}"])
    told: list[str] = []
    closed = asyncio.Event()

    def on_closed() -> None:
        told.append("watched")
        closed.set()

    try:
        watch = drone.watch_links(on_closed)
        drone.watch_links(lambda: told.append("unwatched")).close()
        await serve_reachably(ground, drone, "ground/ping", echo)
        assert told == []
        await ground.close()
        async with asyncio.timeout(10):
            await closed.wait()
        watch.close()
        assert told == ["watched"]
    finally:
        for bus in (drone, ground):
            await bus.close()


async def test_query_without_queryable_is_unreachable_at_once(mesh: MeshFactory) -> None:
    client = await mesh()
    # With a 60 s timeout, a wait for it would end in the test's own timeout: the
    # answer "nobody serves this key" comes without waiting for the timeout.
    with pytest.raises(Unreachable) as info:
        async with asyncio.timeout(30):
            await client.query("drone/nobody/cmd", b"{}", timeout_s=60)
    assert not isinstance(info.value, QueryTimeout)


async def test_a_route_watch_tells_whether_a_query_would_find_a_queryable(mesh: MeshFactory) -> None:
    """At once, then on each change: none, a queryable elsewhere on the mesh (in its
    other key form too), undeclared, and a second watch of the same key beside. Every
    "routed" told is a query answered."""
    server, client = await mesh(), await mesh()
    told: list[bool] = []
    watch = client.watch_route("drone/d7/cmd", told.append)
    assert told == [False]
    served = server.serve("drone/d7/cmd/**", echo)
    await until(lambda: told[-1:] == [True], 10, "the route told")
    assert await client.query("drone/d7/cmd", b"hi", timeout_s=5) == b"hi"
    other: list[bool] = []
    beside = client.watch_route("drone/d7/cmd", other.append)
    assert other == [True]
    served.close()
    await until(lambda: told[-1:] == [False] and other[-1:] == [False], 10, "the route's loss told to both")
    with pytest.raises(Unreachable):
        await client.query("drone/d7/cmd", b"hi", timeout_s=5)
    watch.close()
    server.serve("drone/d7/cmd", echo)
    await until(lambda: other[-1:] == [True], 10, "the route back")
    beside.close()
    assert told == [False, True, False], "a closed watch tells nothing more"


async def test_slow_queryable_times_out(mesh: MeshFactory) -> None:
    server, client = await mesh(), await mesh()
    release = asyncio.Event()

    async def slow(key: str, payload: bytes) -> bytes:
        if payload == b"warm":
            return b"ok"
        await release.wait()
        return b"late"

    await serve_reachably(server, client, "drone/d1/cmd", slow)
    with pytest.raises(QueryTimeout):
        await client.query("drone/d1/cmd", b"slow", timeout_s=0.3)
    release.set()


async def test_failing_queryable_gives_an_error_reply(mesh: MeshFactory) -> None:
    server, client = await mesh(), await mesh()

    async def broken(key: str, payload: bytes) -> bytes:
        if payload == b"warm":
            return b"ok"
        raise ValueError("boom")

    await serve_reachably(server, client, "drone/d1/cmd", broken)
    with pytest.raises(QueryRefused, match="boom"):
        await client.query("drone/d1/cmd", b"x", timeout_s=1)


async def test_liveliness_token_appears_and_vanishes_with_its_session(mesh: MeshFactory) -> None:
    watcher, agent = await mesh(), await mesh()
    events = Collector()
    watcher.watch_liveliness("drone/*/alive", events)
    agent.announce("drone/d7/alive")
    await events.wait_for(lambda e: e == ("drone/d7/alive", True))
    await agent.close()
    await events.wait_for(lambda e: e == ("drone/d7/alive", False))


async def test_liveliness_history_lists_existing_tokens(mesh: MeshFactory) -> None:
    agent, watcher = await mesh(), await mesh()
    token = agent.announce("drone/d8/alive")
    seen = Collector()
    # The token may need a moment to reach the router; a late watcher still sees it.
    deadline = time.monotonic() + 5
    decl = watcher.watch_liveliness("drone/**", seen)
    while not seen.items:
        assert time.monotonic() < deadline, "existing token never listed"
        await asyncio.sleep(0.05)
        decl.close()
        decl = watcher.watch_liveliness("drone/**", seen)
    assert seen.items[0] == ("drone/d8/alive", True)
    token.close()
    await seen.wait_for(lambda e: e == ("drone/d8/alive", False))
