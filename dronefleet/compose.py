"""The composition root: the one place where concrete parts are wired together.

- `run_ground` is the `fleet ground` process: data directory → event log and mission
  store (SQLite) → Zenoh router → station and mission manager → HTTP server. The HTTP
  port is bound before anything listens for drones, so a port in use is a clear error
  at start, not a half-started ground. Cancellation (SIGTERM, Ctrl-C) ends the event
  streams, stops the HTTP server, closes the router and the log.
- `SimField` / `simulate` is fast-time simulation (`fleet mission simulate`, SPEC §5):
  the same GroundStation, mission runtime and agent command handler as in the field,
  with the simulated vehicles of `sim/` behind the agents' `sim` adapter, all joined by
  the in-process memory bus and driven by a VirtualClock: ten minutes of flight take
  seconds, and a run is a function of the script, the world and the seed.
- `dronefleet.demo` wires processes (ground, sims, agents) the same way for `fleet demo`.

Missions see the ground only through `mission.lifecycle.fleet_port.FleetPort`; the GroundStation given
to them here is what implements it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import shutil
import socket
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import uvicorn

from dronefleet.agent.config import AgentConfig
from dronefleet.agent.fc_sim import SimFlightController
from dronefleet.agent.runtime import Agent
from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.datagram_echo import EchoServer
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.bus.mesh_security import certificate_role, mesh_security
from dronefleet.bus.port import Bus
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.ground.api import create_app
from dronefleet.ground.config import DEFAULT_CEILING_M, GroundConfig
from dronefleet.ground.dashboard_routes import open_tile_archive
from dronefleet.ground.eventlog import EventLog
from dronefleet.ground.station import GroundStation
from dronefleet.mission.hosting.manager import MissionManager, MissionStore
from dronefleet.mission.hosting.simulate import add_field_reading, sensor_values, telemetry_sample, write_result
from dronefleet.mission.lifecycle.fleet_port import GroundPort
from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.lifecycle.record import MissionRecord
from dronefleet.mission.script.plugins import PluginLibrary, plugin_summary
from dronefleet.schemas.about import SensorDeclaration
from dronefleet.schemas.endpoints import split_host_port
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.fence import Geofence
from dronefleet.schemas.fleet import WatchEvent
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import Telemetry
from dronefleet.sim.radio import GROUND, RadioModel, Spot3, spot_of
from dronefleet.sim.radio_air import AirEcho, RadioAir
from dronefleet.sim.scratch import scratch_dir
from dronefleet.sim.sensor_publisher import world_field_sensor
from dronefleet.sim.sensors import simulated_sensor
from dronefleet.sim.vehicle import Vehicle
from dronefleet.sim.world import DroneSpec, FieldSensorSpec, World

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


def _loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


def exposure_warnings(config: GroundConfig) -> list[str]:
    """What an operator must know before the field sees this ground (SPEC §9)."""
    warnings = []
    open_links = [e for e in config.listen if e.partition("/")[0] in ("tcp", "udp", "quic", "ws")
                  and not _loopback(split_host_port(e.partition("/")[2].partition("#")[0])[0])]
    if open_links:
        warnings.append(f"the Zenoh router listens on {', '.join(open_links)} without TLS: any machine that reaches it "
                        "can join the mesh and publish as any drone (security.tls, `fleet pki`; deploy/ground-secure.yml)")
    if not _loopback(config.http_host):
        warnings.append(f"the HTTP API is served on {config.http_host} without authentication: anyone who reaches port "
                        f"{config.http_port} can command the drones (keep http_host 127.0.0.1, or put it behind a proxy)")
    return warnings


async def run_ground(config: GroundConfig, out: Callable[[str], None] = lambda line: None) -> None:
    shown = config.security.name or "ground"
    if certificate_role(config.security, "ground") == "observer":
        if config.role != "observer":
            raise ConfigError(f"security: this ground's certificate ({shown}) is issued --role observer, so it may "
                              "only watch: run it with --observer (config role: observer)")
        if config.ground_id != shown:  # the mesh lets an observer speak under ground/<its certificate's name> only
            raise ConfigError(f"ground_id {config.ground_id!r}: an observer's ground_id is its certificate's name "
                              f"({shown!r}), the only ground/<id> the mesh lets it announce")
    data_dir = _prepare_data_dir(config)
    tiles = open_tile_archive(config)
    sock = _bind(config.http_host, config.http_port)
    events = EventLog(data_dir / "events.db")
    store = MissionStore(data_dir / "missions.db")
    plugins = PluginLibrary.default(config.plugins_path.expanduser())
    out(plugin_summary(plugins))
    for warning in exposure_warnings(config):
        out(f"fleet ground: WARNING: {warning}")
    try:
        bus = await ZenohBus.open("router", connect=config.connect, listen=config.listen, extra=mesh_security(
            config.security, "ground", config.listen, router=True, namespace=config.namespace))
        echo = EchoServer(config.listen)  # the agents' delivery probes (link quality)
        try:
            host, port = sock.getsockname()[:2]
            http_url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}/"
            station = GroundStation(config, bus, events, http_url=http_url, epoch_file=data_dir / "ground-epoch")
            station.keep_copies("missions", store.stream(), store.last_change, store)
            station.record_missions(data_dir / "missions")
            missions = MissionManager(station, store, station.clock, plugins=plugins, isolate=True,
                                      check_commanding=station.check_commanding)
            station.on_takeover = missions.take_over
            server = _EmbeddedServer(uvicorn.Config(
                create_app(station, missions, tiles), log_level="warning", lifespan="on",
                timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
            ))
            out(f"fleet ground: Zenoh router on {', '.join(config.listen)}; data in {data_dir}")
            if config.connect:
                out(f"fleet ground: {config.ground_id} (priority {config.priority}, {config.role}) joins "
                    f"{', '.join(config.connect)}")
            out(f"fleet ground: API on {http_url} (OpenAPI at /openapi.json)")
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
            echo.close()
            await bus.close()
    finally:
        store.close()
        events.close()
        sock.close()


# ---- fast-time simulation --------------------------------------------------

STEP_S = 1.0  # how far virtual time moves between checks for the mission's end
DEFAULT_MAX_S = 3600.0


@dataclass
class Track:
    samples: list[dict[str, Any]] = field(default_factory=list)  # what the ground heard
    flown: list[dict[str, Any]] = field(default_factory=list)  # on the radio: where the drone was, heard or not


class SimField:
    """A ground and simulated drones on one memory bus under one virtual clock."""

    def __init__(
        self,
        world: World,
        n: int | None = None,
        *,
        seed: int = 0,
        telemetry_rate_ms: int = 1000,
        ground_config: GroundConfig | None = None,
        data_dir: Path | None = None,
        plugins: PluginLibrary | None = None,
        radio: RadioModel | None = None,
        agent_config: AgentConfig | None = None,
        fleet_port: Callable[[GroundStation], GroundPort] | None = None,
        agent_bus: Callable[[str, Bus], Bus] | None = None,
        predicting: bool = False,
    ) -> None:
        """`fleet_port` and `agent_bus` are fault-injection points: what the missions
        reach the ground through, made from the station (by default the station itself),
        and each agent's bus, made from its drone's id and session; a test wraps them to
        make a call fail or a message go missing (bus/faulty.py). `predicting`: the
        world is a preflight's copy of a live fleet, and each mission's first read of what
        that copy cannot know (`unknowns`) goes into its result (ADR 0014)."""
        self.predicting = predicting
        self.unknowns: dict[str, dict[str, Any]] = {}  # mission id → {line, what} of its first such read
        self.world = world
        self.specs = world.spawn(n)
        self.seed = seed
        self.clock = VirtualClock()
        self.vehicles: dict[str, Vehicle] = {}
        # The radio (world `radio:` or the argument): links follow the vehicles.
        radio = radio or world.radio
        self._agent_runtimes: dict[str, Agent] = {}
        self.air = RadioAir(radio, self._where, self.clock, seed, agent=self._agent_runtimes.get) if radio is not None else None
        self.network = MemoryNetwork(medium=self.air)
        self._tmp = scratch_dir() if data_dir is None else None
        self.data_dir = data_dir or Path(self._tmp.name)  # type: ignore[union-attr]
        self.config = ground_config or GroundConfig(data_dir=str(self.data_dir))
        self.agent_config = agent_config or AgentConfig(telemetry_rate_ms=telemetry_rate_ms)
        if world.geofence is not None:  # the world's fence, unless the caller set one
            if self.config.geofence == Geofence(max_alt_m=DEFAULT_CEILING_M):  # none configured
                self.config = msgspec.structs.replace(self.config, geofence=world.geofence)
            if self.agent_config.geofence == Geofence():
                self.agent_config = msgspec.structs.replace(self.agent_config, geofence=world.geofence)
        self.tracks: dict[str, Track] = {}
        self.field_sensors: dict[str, dict[str, Any]] = {}  # what the ground heard of them (result.json)
        self._tasks: list[asyncio.Task[Any]] = []
        self._agents: dict[str, asyncio.Task[Any]] = {}
        self._buses: list[MemoryBus] = []
        self._fcs: list[SimFlightController] = []
        self.events = EventLog(self.data_dir / "events.db")
        self.station = GroundStation(self.config, self._bus(GROUND), self.events, self.clock)
        ids = random.Random(f"ids {seed}")
        self.station.new_command_id = lambda: str(uuid.UUID(int=ids.getrandbits(128), version=4))
        self.station.new_bundle_id = lambda: f"b-{ids.getrandbits(48):012x}"
        self.manager: MissionManager | None = None
        self.plugins = plugins if plugins is not None else PluginLibrary.default(None)
        self._fleet_port = fleet_port
        self._agent_bus = agent_bus

    def _bus(self, node: str = GROUND) -> MemoryBus:
        """A session on `node` of the mesh: the ground, or a drone (its agent and on-board programs)."""
        bus = MemoryBus(self.network, node)
        self._buses.append(bus)
        return bus

    def _where(self) -> dict[str, Spot3]:
        return {GROUND: self.world.ground_spot3(), **{k: spot_of(v.position()) for k, v in self.vehicles.items()}}

    async def start(self, echo: Callable[[float, str], None] | None = None) -> None:
        loop = asyncio.get_running_loop()
        if self.air is not None:
            self._tasks.append(loop.create_task(self.air.run(), name="radio"))
        self._tasks.append(loop.create_task(self.station.run(), name="ground"))
        self.station.listen(self._record)
        gs = self.world.ground_station or self.world.origin
        self.station.record_missions(self.data_dir / "missions", ground_station=(gs.lat, gs.lon))
        for spec in self.specs:
            vehicle = self.world.vehicle(spec, spec.autopilot)
            self.vehicles[spec.id] = vehicle
            self.tracks[spec.id] = Track()
            fc = SimFlightController(vehicle, self.clock)
            await fc.start()
            self._fcs.append(fc)
            if self.air is not None:
                self.air.tick()  # the new drone's links
            datagrams = AirEcho(self.air, spec.id) if self.air is not None else None
            bus: Bus = self._bus(spec.id)
            if self._agent_bus is not None:
                bus = self._agent_bus(spec.id, bus)
            agent = Agent(spec.id, self._agent_config(spec), fc, bus, self.clock, echo=datagrams)
            self._agent_runtimes[spec.id] = agent
            self._agents[spec.id] = loop.create_task(agent.run(), name=f"agent {spec.id}")
            self._tasks.append(self._agents[spec.id])
            for fault in spec.faults:
                self._tasks.append(loop.create_task(self._fault_at(vehicle, fault.at_s, fault.fault, fault.value)))
            if spec.sensors:
                self._tasks.append(loop.create_task(self._sensors(spec.id, self.world.declarations(spec))))
        for field_sensor in self.world.field_sensors:
            self._tasks.append(loop.create_task(self._field_sensor(field_sensor), name=f"field sensor {field_sensor.id}"))
        store = MissionStore(self.data_dir / "missions.db")
        port = self.station if self._fleet_port is None else self._fleet_port(self.station)
        self.manager = MissionManager(port, store, self.clock, deterministic=True, seed=self.seed, plugins=self.plugins)
        if echo is not None:
            self.manager.echo = lambda mission_id, line: echo(self.clock.monotonic(), line.message)
        if self.predicting:
            self.manager.on_unknowable = self._unknowable
        # Let every drone register (first telemetry) with its sensors before the mission
        # starts; on the radio, every drone the ground can reach.
        await self.clock.advance(self.agent_config.telemetry_rate_ms / 1000 + 0.1)
        for _ in range(100):
            if all(set(spec.sensor_types) <= set(self._sensors_of(spec.id)) for spec in self.specs
                   if self.air is None or self.air.reachable(spec.id, GROUND)):
                break
            await self.clock.advance(0.1)
        else:
            raise RuntimeError("simulated drones did not register with their sensors within 10 s")

    def _unknowable(self, mission: Mission, line: int | None, what: str) -> None:
        if mission.id not in self.unknowns:
            self.unknowns[mission.id] = {"line": line, "what": what}
            where = f"line {line}" if line is not None else "a plugin"
            mission.log("info", f"Prediction: {where} reads {what}, which a preflight cannot know; "
                                "from here on the prediction is a guess and refuses nothing")

    def _agent_config(self, spec: DroneSpec) -> AgentConfig:
        """The agents' config with what this drone is (its world entry's kind, roles, sensors)."""
        config = msgspec.structs.replace(self.agent_config, sensors=self.world.declarations(spec))
        if spec.kind is not None:
            config = msgspec.structs.replace(config, kind=spec.kind)
        if spec.roles is not None:
            config = msgspec.structs.replace(config, roles=list(spec.roles))
        return config

    async def _field_sensor(self, spec: FieldSensorSpec) -> None:
        """A world's field sensor on the mesh (its own session, wired to the ground)."""
        await world_field_sensor(self._bus(f"sensor {spec.id}"), self.world, spec, self.clock, Keys(self.config.namespace))

    def _sensors_of(self, drone_id: str) -> list[str]:
        registry = self.station.registry
        return registry.info(drone_id).sensors if drone_id in registry else []

    def kill_agent(self, drone_id: str) -> None:
        """The agent process dies: its liveliness token and telemetry vanish."""
        self._agents[drone_id].cancel()

    async def _fault_at(self, vehicle: Vehicle, at_s: float, fault: str, value: Any) -> None:
        from dronefleet.sim.faults import apply_fault

        await self.clock.sleep(at_s)
        apply_fault(vehicle, fault, value)

    async def _sensors(self, drone_id: str, declared: list[SensorDeclaration]) -> None:
        """Simulated on-board sensors (sim/sensors.py), following the drone's telemetry."""
        bus = self._bus(drone_id)  # on board: connected to its own agent
        keys = Keys(self.config.namespace)
        tasks = [asyncio.ensure_future(simulated_sensor(bus, drone_id, d.type, self.world, clock=self.clock, keys=keys,
                                                        fields=list(d.fields)))
                 for d in declared]
        try:
            await asyncio.gather(*tasks)
        finally:
            for task in tasks:
                task.cancel()

    def _record(self, event: WatchEvent) -> None:
        if event.kind == "telemetry":
            t: Telemetry = event.data
            track = self.tracks.get(t.drone_id)
            if track is None or t.position is None:
                return
            registry = self.station.registry
            info = registry.info(t.drone_id)
            sensors = sensor_values(registry.sensor_readings(t.drone_id))
            track.samples.append(telemetry_sample(t, self.clock.monotonic(), info.state, sensors, info.link))
        elif event.kind == "field_sensor":
            add_field_reading(self.field_sensors, event.data, self.clock.monotonic())

    def _fly_log(self) -> None:
        """On the radio the ground may not hear a drone: keep its true path beside."""
        if self.air is None:
            return
        for drone_id, track in self.tracks.items():
            p = self.vehicles[drone_id].position()
            track.flown.append({"t_s": round(self.clock.monotonic(), 3), "lat": p.lat, "lon": p.lon, "rel_alt": p.rel_alt})

    async def run_mission(self, source: str, *, name: str = "", max_s: float = DEFAULT_MAX_S,
                          enable: dict[str, dict[str, Any]] | None = None) -> MissionRecord:
        assert self.manager is not None
        record = self.manager.submit(source, name, enable)
        return await self.run_mission_started(record.mission_id, max_s=max_s)

    async def run_mission_started(self, mission_id: str, *, max_s: float = DEFAULT_MAX_S) -> MissionRecord:
        """Advance virtual time until the mission ends (cancelled after `max_s`)."""
        assert self.manager is not None
        task = asyncio.ensure_future(self.manager.wait(mission_id))
        start = self.clock.monotonic()
        limited = False
        while not task.done():
            if self.clock.monotonic() - start >= max_s and not limited:
                limited = True
                message = f"simulation time limit of {max_s:g} s reached" + self._still_doing(mission_id)
                self.station.log_ground("warn", message)
                self.manager.cancel(mission_id, "time_limit", message)
            self._fly_log()
            await self.clock.advance(STEP_S)
        # One more telemetry period so the series shows the state the mission left.
        await self.clock.advance(self.agent_config.telemetry_rate_ms / 1000)
        return task.result()

    def _still_doing(self, mission_id: str) -> str:
        """What a mission's subroutines were doing when time ran out (a mission that waits
        on the world — a sensor, a field alarm — says what for)."""
        assert self.manager is not None
        doing = []
        for a in self.manager.lanes(mission_id).subroutines.values():
            if a.event in ("waiting", "verb") and a.plugin is None:
                what = f"waiting on {a.waiting_on}" if a.event == "waiting" and a.waiting_on else a.verb
                doing.append(f"{a.name}: {what}" + (f" at line {a.line}" if a.line is not None else ""))
        return f"; still running: {'; '.join(doing)}" if doing else ""

    async def until(self, predicate: Callable[[], bool], max_s: float = 600.0) -> None:
        """Let virtual time pass (in small steps) until `predicate` holds."""
        start = self.clock.monotonic()
        while not predicate():
            if self.clock.monotonic() - start > max_s:
                raise TimeoutError(f"not within {max_s:g} simulated seconds")
            await asyncio.sleep(0)

    def mission_log(self, mission_id: str) -> list[Any]:
        assert self.manager is not None
        return self.manager.store.log(mission_id)

    def result(self, record: MissionRecord) -> dict[str, Any]:
        assert self.manager is not None
        mission = self.manager.store.log(record.mission_id)
        lanes = self.manager.lanes(record.mission_id)
        gs = self.world.ground_station or self.world.origin
        return {
            "mission": msgspec.to_builtins(record),
            "log": [msgspec.to_builtins(line) for line in mission],
            # what each subroutine last did, and the plugins' actions (the dashboard's lanes)
            "subroutines": [msgspec.to_builtins(a) for a in lanes.subroutines.values()],
            "marks": [msgspec.to_builtins(a) for a in lanes.marks],
            "seed": self.seed,
            "t0_ms": self.clock.time_ms() - round(self.clock.monotonic() * 1000),  # wall time of t_s = 0
            "ground_station": {"lat": gs.lat, "lon": gs.lon},
            **({"geofence": msgspec.to_builtins(self.config.geofence)} if self.config.geofence.limits else {}),
            "drones": {
                drone_id: {
                    "samples": track.samples,
                    **({"flown": track.flown} if track.flown else {}),
                    "commands": [msgspec.to_builtins(c) for c in self.manager.commands if c.drone_id == drone_id],
                }
                for drone_id, track in sorted(self.tracks.items())
            },
            **({"field_sensors": self.field_sensors} if self.field_sensors else {}),
            **({"unknown": self.unknowns[record.mission_id]} if record.mission_id in self.unknowns else {}),
        }

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        for fc in self._fcs:
            await fc.close()
        for bus in self._buses:
            await bus.close()
        if self.manager is not None:
            self.manager.store.close()
        self.events.close()
        if self._tmp is not None:
            self._tmp.cleanup()


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)


async def simulate(
    source: str,
    world: World,
    *,
    n: int | None = None,
    seed: int = 0,
    out_dir: Path | None = None,
    name: str = "",
    max_s: float = DEFAULT_MAX_S,
    echo: Callable[[float, str], None] | None = None,
    plots: bool = True,
    plugins: PluginLibrary | None = None,
    enable: dict[str, dict[str, Any]] | None = None,
    predicting: bool = False,
) -> dict[str, Any]:
    """Run one script to its end under virtual time; write result.json and plots to out_dir.
    `predicting`: the world is a preflight's copy of the live fleet (SimField)."""
    sim = SimField(world, n, seed=seed, plugins=plugins, predicting=predicting)
    try:
        await sim.start(echo)
        record = await sim.run_mission(source, name=name, max_s=max_s, enable=enable)
        result = sim.result(record)
        if out_dir is not None:  # the mission's recording (SPEC §12), before its data dir goes
            await asyncio.to_thread(_copy, sim.data_dir / "missions" / f"{record.mission_id}.mcap",
                                    out_dir / "recording.mcap")
    finally:
        await sim.close()
    if out_dir is not None:
        await asyncio.to_thread(write_result, result, out_dir, plots)
    return result
