"""The `fleet ground` process: resources opened in order, closed in reverse.

Data directory → event log and mission store (SQLite) → Zenoh router → station and
mission manager → HTTP server. The
HTTP port is bound before anything listens for drones, so a port in use is a clear
error at start, not a half-started ground. Cancellation (SIGTERM, Ctrl-C) ends the
event streams, stops the HTTP server, closes the router and the log.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from collections.abc import Callable, Iterator
from pathlib import Path

import uvicorn

from bus.zenoh_bus import ZenohBus
from ground.api import create_app
from ground.config import GroundConfig
from ground.eventlog import EventLog
from ground.station import GroundStation
from mission.manager import MissionManager, MissionStore
from mission.plugins import PluginLibrary, plugin_summary
from schemas.errors import ConfigError

log = logging.getLogger(__name__)
SHUTDOWN_GRACE_S = 3


class _EmbeddedServer(uvicorn.Server):
    """uvicorn inside our loop: the process's signal handling stays ours."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


def _bind(host: str, port: int) -> socket.socket:
    # proto=IPPROTO_TCP matters: asyncio sets TCP_NODELAY only on sockets that say so,
    # and without it every keep-alive response waits ~40 ms for a delayed ACK.
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ConfigError(f"cannot serve HTTP on {host}:{port}: {exc.strerror} (choose another with --http-port)") from None
    sock.listen(128)
    sock.setblocking(False)
    return sock


def _prepare_data_dir(config: GroundConfig) -> Path:
    path = Path(config.data_dir).expanduser()
    try:
        path.mkdir(parents=True, exist_ok=True)
        config.plugins_path.expanduser().mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"data_dir {str(path)!r}: cannot create: {exc.strerror}") from None
    return path


async def run_ground(config: GroundConfig, out: Callable[[str], None] = lambda line: None) -> None:
    data_dir = _prepare_data_dir(config)
    sock = _bind(config.http_host, config.http_port)
    events = EventLog(data_dir / "events.db")
    store = MissionStore(data_dir / "missions.db")
    plugins = PluginLibrary.default(config.plugins_path.expanduser())
    out(plugin_summary(plugins))
    try:
        bus = await ZenohBus.open("router", listen=config.listen)
        try:
            station = GroundStation(config, bus, events)
            missions = MissionManager(station, store, station.clock, plugins=plugins)
            server = _EmbeddedServer(uvicorn.Config(
                create_app(station, missions), log_level="warning", lifespan="on",
                timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
            ))
            host, port = sock.getsockname()[:2]
            out(f"fleet ground: Zenoh router on {', '.join(config.listen)}; data in {data_dir}")
            out(f"fleet ground: API on http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}/ (OpenAPI at /openapi.json)")
            async with asyncio.TaskGroup() as tg:
                station_task = tg.create_task(station.run(), name="ground station")
                http_task = tg.create_task(server.serve(sockets=[sock]), name="ground http")
                try:
                    await asyncio.Event().wait()
                finally:
                    await missions.close()  # while the mesh is up: drones are told to hold
                    station.end_watches()
                    server.should_exit = True
                    await asyncio.wait([http_task])
                    station_task.cancel()
        finally:
            await bus.close()
    finally:
        store.close()
        events.close()
        sock.close()
