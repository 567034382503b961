"""The Bus on a real Eclipse Zenoh session (eclipse-zenoh 1.10).

Configuration follows what was measured on these machines (SPEC §2, ADR 0003): every
node announces a 2 s lease so a silent drone's liveliness vanishes in ≈ 2 s (a
killed one's at once; 4 s for a while in issue 30, back to 2 s once drones stopped
holding links to lossy neighbours);
multicast scouting is off unless a mesh interface is named; peers do not gossip (so
traffic goes through the routers and their access rules); a router opens with no
scouting delay. A router that also connects out (a drone's agent, a mesh node) never
waits for the ground at open and retries it every second. On a wired network it
connects to the routers it learns of by gossip; on a radio (`mesh_interface`) it only
answers scouts, and its agent links it through neighbours while its direct link fails
(agent/neighbours.py). Routers form a link-state mesh that carries a drone's traffic
through a neighbour. Telemetry goes out
with congestion control DROP, everything else with BLOCK from the publisher; every router
then forwards data and queries with DROP and gives up a blocked push in 0.1 s, and
Zenoh's acceptor runs on 2 threads (ADR 0003: nothing that crosses the radio may hold
a router). Callbacks run on Zenoh
threads: they only hand off into bounded inboxes or the loop and return.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import re
import threading
from collections.abc import Callable, Sequence
from typing import Any, Literal

import zenoh

from dronefleet.bus.inbox import Inbox
from dronefleet.bus.port import (
    BusError,
    LivelinessHandler,
    NoRoute,
    QueryHandler,
    QueryRefused,
    QueryTimeout,
    RouteHandler,
    Sample,
    SampleHandler,
)
from dronefleet.bus.route_watch import RouteWatches
from dronefleet.bus.sockets import LingerOff

log = logging.getLogger(__name__)
Mode = Literal["client", "peer", "router"]
DEFAULT_LEASE_MS = 2000  # with links through neighbours only when needed, 2 s holds (ADR 0003)
BLOCK_WAIT_US = 100_000  # a blocked push gives up after 0.1 s (Zenoh's default: 5 s; ADR 0003)
QUEUE_BATCHES = 16  # per priority, Zenoh's maximum (default 2)
_PRIORITIES = ("control", "real_time", "interactive_high", "interactive_low", "data_high", "data", "data_low", "background")
# Zenoh forwards a message on the receiving link's thread; by default 2 such threads
# serve every link, so two pushes waiting on one bad neighbour starve every other link.
# The acceptor runs every link's handshake on 1 thread by default: a drone redialling
# the ground waited there behind a handshake over a lossy hop (8 s, ADR 0003).
# Read once when Zenoh starts its runtimes: set before it does; an operator's wins.
RX_THREADS = 4
CLOSE_WAIT_S = 2.0  # `session.close()` may block ~10 s with a lossy link open (upstream #2675): not waited longer
ACC_THREADS = 2
os.environ.setdefault("ZENOH_RUNTIME", f"(rx: (worker_threads: {RX_THREADS}), acc: (worker_threads: {ACC_THREADS}))")

# Zenoh's own log (links opening and closing, why a connect failed) goes to stdout when
# RUST_LOG asks for it, e.g. RUST_LOG=zenoh=debug; errors only otherwise.
zenoh.init_log_from_env_or("error")


def zenoh_config(
    mode: Mode,
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    *,
    lease_ms: int = DEFAULT_LEASE_MS,
    mesh_interface: str | None = None,
    extra: dict[str, Any] | None = None,
) -> zenoh.Config:
    conf = zenoh.Config()

    def put(path: str, value: Any) -> None:
        conf.insert_json5(path, json.dumps(value))

    put("mode", mode)
    put("scouting/multicast/enabled", False)
    if connect:
        put("connect/endpoints", list(connect))
    if listen:
        put("listen/endpoints", list(listen))
    put("transport/link/tx/lease", lease_ms)
    if mode == "router":
        put("scouting/delay", 0)
        # Drones dial the routers they learn of (neighbours, for relaying). The ground
        # (no `connect`) dials no one: each drone's link to it is the drone's own, so
        # there is one link per drone. Seen in bench/mesh.py (Zenoh debug log): when
        # the ground also dialled back, a pair held two links, and after the radio was
        # cut the ground kept the second one 7 s past its 2 s lease (ADR 0003).
        # On a radio (`mesh_interface`) a drone dials no neighbour by itself either: its
        # agent links through neighbours only while it needs them (agent/neighbours.py).
        dials = ["router"] if connect and not mesh_interface else []
        put("scouting/gossip/autoconnect", {"router": dials, "peer": ["router", "peer"]})
        if connect:
            # Measured (zenoh 1.10.2): 0 never retries an endpoint that was down at
            # open; 1 ms returns at once and retries every period, for ever.
            put("connect/timeout_ms", 1)
            put("connect/exit_on_failure", False)
            put("connect/retry", {"period_init_ms": 500, "period_max_ms": 1000, "period_increase_factor": 2})
        if mesh_interface:
            put("scouting/multicast/enabled", True)
            put("scouting/multicast/interface", mesh_interface)
            put("scouting/multicast/listen", True)
            # Listen: answer the neighbours' agents' scouts; never autoconnect (above).
            put("scouting/multicast/autoconnect", {"router": [], "peer": ["router", "peer"]})
    if mode == "peer":
        put("scouting/gossip/enabled", False)
    if mode == "router":
        # Nothing a router forwards may hold it for long (ADR 0003, bench/mesh_stall.py):
        # a push that finds no room towards a neighbour that stopped reading gives up
        # (and closes that link) in 0.1 s instead of 5 s: the thread that waits is the
        # one reading another link, and several such pushes in a row must stay well
        # inside that link's lease;
        # deeper queues absorb a burst before anything waits; and data and queries
        # are dropped rather than waited for when a link is congested (what must not
        # be lost is caught up end to end: statuses repeated, bundle records read).
        put("transport/link/tx/queue/congestion_control/block/wait_before_close", BLOCK_WAIT_US)
        put("transport/link/tx/queue/size", dict.fromkeys(_PRIORITIES, QUEUE_BATCHES))
        put("qos/network", [{
            "id": "radio-never-blocks", "messages": ["put", "delete", "query"], "flows": ["egress"],
            "overwrite": {"congestion_control": "drop"},
        }])
    for path, value in (extra or {}).items():
        put(path, value)
    return conf


def zenoh_message(exc: BaseException) -> str:
    """A Zenoh error without the Rust source locations it carries (`at /root/.cargo/…rs:61.`)."""
    return _RUST_LOCATION.sub("", str(exc)).strip()


_RUST_LOCATION = re.compile(r"\s*at /\S+?\.rs:\d+\.?")


class _Declared:
    def __init__(self, undeclare: Any, inbox: Inbox[Any] | None = None) -> None:
        self._undeclare = undeclare
        self._inbox = inbox
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._inbox is not None:
            self._inbox.close()
        try:
            self._undeclare()
        except zenoh.ZError:  # session already closed
            pass


class ZenohBus:
    """One Zenoh session; create with `await ZenohBus.open(...)`, always `close()`."""

    def __init__(self, session: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        self._session = session
        self._loop = loop
        self._publishers: dict[tuple[str, bool], zenoh.Publisher] = {}
        self._decls: list[_Declared] = []
        self._query_tasks: set[asyncio.Task[None]] = set()
        self._routes: RouteWatches | None = None  # created with the first route watch
        self._closed = False

    @classmethod
    async def open(
        cls,
        mode: Mode,
        connect: Sequence[str] = (),
        listen: Sequence[str] = (),
        *,
        wait: bool = False,
        retry_s: float = 1.0,
        lease_ms: int = DEFAULT_LEASE_MS,
        mesh_interface: str | None = None,
        extra: dict[str, Any] | None = None,
    ) -> ZenohBus:
        """Open a session. With `wait`, a client retries until a router answers
        (logging each attempt) instead of failing; cancellation stops the wait."""
        conf_args = (mode, connect, listen)
        LingerOff.start()  # Zenoh's links linger 10 s on close, holding a router's thread (ADR 0003)
        attempt = 0
        while True:
            attempt += 1
            try:
                session = await asyncio.to_thread(
                    zenoh.open, zenoh_config(*conf_args, lease_ms=lease_ms, mesh_interface=mesh_interface, extra=extra)
                )
                return cls(session, asyncio.get_running_loop())
            except zenoh.ZError as exc:
                if not wait:
                    raise BusError(f"cannot open Zenoh {mode} session ({', '.join(connect or listen)}): {zenoh_message(exc)}") from None
                if attempt == 1 or attempt % 10 == 0:
                    log.warning("waiting for a Zenoh router at %s: %s", ", ".join(connect), exc)
                await asyncio.sleep(retry_s)

    @property
    def session(self) -> zenoh.Session:
        """The Zenoh session itself, for what the Bus port does not carry (its links)."""
        return self._session

    def publish(self, key: str, payload: bytes, *, reliable: bool = True) -> None:
        pub = self._publishers.get((key, reliable))
        if pub is None:
            pub = self._session.declare_publisher(
                key,
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=(
                    zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
                ),
            )
            self._publishers[(key, reliable)] = pub
        pub.put(payload)

    def subscribe(
        self, keyexpr: str, handler: SampleHandler, *, latest_only: bool = False, maxsize: int = 1024
    ) -> _Declared:
        inbox: Inbox[Sample] = Inbox(
            self._loop, handler, name=f"sub {keyexpr}", latest_only=latest_only, maxsize=maxsize
        )

        def on_sample(sample: zenoh.Sample) -> None:
            kind: Literal["put", "delete"] = "delete" if sample.kind == zenoh.SampleKind.DELETE else "put"
            inbox.put(Sample(str(sample.key_expr), sample.payload.to_bytes(), kind))

        sub = self._session.declare_subscriber(keyexpr, on_sample)
        return self._keep(_Declared(sub.undeclare, inbox))

    def serve(self, keyexpr: str, handler: QueryHandler) -> _Declared:
        def on_query(query: zenoh.Query) -> None:
            try:
                self._loop.call_soon_threadsafe(self._start_answer, query, handler)
            except RuntimeError:  # loop closed: let the querier time out
                query.drop()

        queryable = self._session.declare_queryable(keyexpr, on_query)
        return self._keep(_Declared(queryable.undeclare))

    def _start_answer(self, query: zenoh.Query, handler: QueryHandler) -> None:
        task = self._loop.create_task(self._answer(query, handler), name=f"answer {query.key_expr}")
        self._query_tasks.add(task)
        task.add_done_callback(self._query_tasks.discard)

    async def _answer(self, query: zenoh.Query, handler: QueryHandler) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            params = str(query.parameters)
            reply = await handler(f"{query.key_expr}?{params}" if params else str(query.key_expr), payload)
            query.reply(query.key_expr, reply, encoding=zenoh.Encoding.APPLICATION_JSON)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("queryable %s failed", query.key_expr)
            query.reply_err(str(exc).encode())
        finally:
            query.drop()  # finalises the query: the querier's get ends now

    async def query(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> bytes:
        return (await self._query(selector, payload, timeout_s))[0]

    async def query_linked(self, selector: str, payload: bytes = b"", *, timeout_s: float = 2.0) -> tuple[bytes, bool | None]:
        reply, replier = await self._query(selector, payload, timeout_s)
        if replier is None:
            return reply, None
        # A router linked to this one has a transport of its own here (measured: three
        # routers in a row, gossip autoconnect off as on the radio; the far one's
        # replies come through the middle one, whose transport it is).
        return reply, replier in {str(t.zid) for t in self._session.info.transports()}

    async def _query(self, selector: str, payload: bytes, timeout_s: float) -> tuple[bytes, str | None]:
        """The first good reply's payload and the ZID of the node that sent it."""
        done: asyncio.Future[list[zenoh.Reply]] = self._loop.create_future()
        replies: list[zenoh.Reply] = []

        def finish() -> None:
            if not done.done():
                done.set_result(replies)

        def on_done() -> None:
            try:
                self._loop.call_soon_threadsafe(finish)
            except RuntimeError:
                pass

        # The default handler starts a Python thread per query (three a second for the
        # probes). Running these callbacks on Zenoh's own thread (indirect=False) saves it,
        # but an agent then once failed to stop on SIGTERM within 10 s (a fresh-clone run):
        # a Zenoh thread waiting for the GIL while the loop closes the session is the
        # suspected deadlock, so not until that is ruled out (ADR 0003, "What it costs").
        self._session.get(
            selector,
            zenoh.handlers.Callback(replies.append, on_done),
            payload=payload,
            timeout=timeout_s,
        )
        # Zenoh enforces the timeout itself; the margin only guards a lost `on_done`.
        async with asyncio.timeout(timeout_s + 1.0):
            result = await done
        errors: list[str] = []
        for reply in result:
            if reply.ok is not None:
                return reply.ok.payload.to_bytes(), str(reply.replier_id.zid) if reply.replier_id is not None else None
            if reply.err is not None:
                errors.append(reply.err.payload.to_string())
        if not errors:
            raise NoRoute(f"no queryable answers {selector}")
        if any(e == "Timeout" for e in errors):
            raise QueryTimeout(f"no reply from {selector} within {timeout_s:g} s")
        raise QueryRefused(f"{selector}: {'; '.join(errors)}")

    def announce(self, key: str) -> _Declared:
        token = self._session.liveliness().declare_token(key)
        return self._keep(_Declared(token.undeclare))

    def watch_liveliness(self, keyexpr: str, handler: LivelinessHandler) -> _Declared:
        inbox: Inbox[tuple[str, bool]] = Inbox(
            self._loop, lambda item: handler(*item), name=f"liveliness {keyexpr}", maxsize=4096
        )

        def on_sample(sample: zenoh.Sample) -> None:
            inbox.put((str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

        sub = self._session.liveliness().declare_subscriber(keyexpr, on_sample, history=True)
        return self._keep(_Declared(sub.undeclare, inbox))

    def watch_route(self, key: str, handler: RouteHandler) -> _Declared:
        """Polled, not pushed (bus/route_watch.py): a change is told within
        route_watch.SWEEP_S, an unrouted key's route within POLL_S."""
        if self._routes is None:
            self._routes = RouteWatches(self._session, self._loop)
        watch = self._routes.watch(key, handler)
        return self._keep(_Declared(watch.close))

    def watch_links(self, on_closed: Callable[[], None]) -> _Declared:
        def tell() -> None:  # on the loop: not once the watch or the session is closed
            if not (decl.closed or self._closed):
                on_closed()

        def on_event(event: zenoh.LinkEvent) -> None:  # on a Zenoh thread
            if event.kind == zenoh.SampleKind.DELETE:
                self._loop.call_soon_threadsafe(tell)

        listener = self._session.info.declare_link_events_listener(on_event)
        decl = _Declared(listener.undeclare)
        return self._keep(decl)

    def _keep(self, decl: _Declared) -> _Declared:
        self._decls.append(decl)
        return decl

    async def close(self) -> None:
        """Undeclare everything and close the session; a second call does nothing."""
        if self._closed:
            return
        self._closed = True
        for task in list(self._query_tasks):
            task.cancel()
        if self._routes is not None:
            self._routes.close()
        for decl in reversed(self._decls):
            decl.close()
        self._decls.clear()
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except zenoh.ZError:
                pass
        self._publishers.clear()
        await self._close_session()

    async def _close_session(self) -> None:
        """`session.close()` on a daemon thread, waited CLOSE_WAIT_S at most: with a link
        to a peer that went silent or lossy it blocks about 10 s before it gives up
        (upstream #2675, a regression of #2012 by #2173; fix #2733 not released), and a
        ground told to stop must stop (the process exits with that thread unfinished)."""
        loop = asyncio.get_running_loop()
        done = loop.create_future()

        def close() -> None:
            try:
                self._session.close()
            except zenoh.ZError as exc:
                log.info("zenoh: closing the session: %s", exc)
            finally:
                try:
                    loop.call_soon_threadsafe(_settle, done)
                except RuntimeError:
                    pass  # the loop is gone: nobody waits

        threading.Thread(target=close, name="zenoh-close", daemon=True).start()
        try:
            await asyncio.wait_for(asyncio.shield(done), CLOSE_WAIT_S)
        except TimeoutError:
            log.warning("zenoh: the session did not close within %g s (a link to a silent peer; upstream #2675); "
                        "going on without waiting", CLOSE_WAIT_S)


def _settle(done: asyncio.Future[None]) -> None:
    if not done.done():
        done.set_result(None)
