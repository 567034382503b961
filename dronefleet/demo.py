"""`fleet demo` (`make demo`): a ground, three simulated drones and the fire-tracing mission.

In this process: a ground station (`run_ground`: Zenoh router, registry, event log in
a temporary directory, mission manager, HTTP API), the simulated on-board sensors of
the world file (`sim/sensors.py`, on a Zenoh client) and a recorder of every drone's
telemetry. As child processes: one `fleet agent --fc sim://?lat=…` per drone of the
world (default `examples/worlds/fire.yml`: drone01 carries a temperature sensor near a
fire; agents' logs go to OUT/logs/). Once the API answers and every drone is `ready`
with its sensors, `examples/fire_tracing.py` is submitted over HTTP and followed by
polling `GET /mission/{id}`: each mission log line is printed as it appears, with a
one-line status of the sensor drone every few seconds. When the mission ends, the
recorded time series go to OUT/result.json (the shape of `fleet mission simulate`'s)
with its four plots, and the ground's event log to OUT/ground.log.

Then, with `--until-done`, the demo stops and exits 0 if the mission finished with
success, 1 otherwise; without it the ground and drones stay up until Ctrl-C. A mission
running longer than `--max-time` is cancelled (DELETE /mission/{id}) and the demo
exits 1. Ctrl-C or SIGTERM at any point stops the agents, the sensors, the Zenoh
client and the ground. Every wait has a deadline, and a ground, agent or sensor that
stops on its own ends the demo with its error (a port in use, for instance).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import subprocess
import tempfile
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import httpx

from dronefleet import examples
from dronefleet.bus.port import Bus, Sample
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.compose import run_ground
from dronefleet.ground.config import DashboardSettings, GroundConfig
from dronefleet.mission.hosting.simulate import add_field_reading, telemetry_sample
from dronefleet.mission_cli import PREFLIGHT_WAIT_S, outcome, preflight_summary
from dronefleet.schemas.codec import decode_sensor, decode_telemetry
from dronefleet.schemas.config_loading import MissionSettings, writable_dir
from dronefleet.schemas.errors import ConfigError, FleetError
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.telemetry import Telemetry
from dronefleet.sim.agent_command import agent_command, drone_agent_config
from dronefleet.sim.projection import LocalFrame
from dronefleet.sim.sensor_publisher import world_field_sensor
from dronefleet.sim.sensors import simulated_sensor
from dronefleet.sim.world import DroneSpec, World, load_world

DEFAULT_WORLD = examples.WORLDS / "fire.yml"
SCRIPT = examples.DIR / "fire_tracing.py"

MAP_ZOOMS = range(15, 19)  # the demo's map: the field in a tile or two at 15, 0.6 m a pixel at 18 (scaled closer)
TELEMETRY_RATE_MS = 200  # the agents' telemetry period, also the recorder's sampling period
POLL_S = 0.5  # mission record and drone states
STATUS_EVERY_S = 5.0
DEMO_PREFLIGHT_S = 600.0  # simulated seconds its submission's preflight may run
HTTP_READY_S = 30.0
DRONES_READY_S = 120.0  # three Python agents starting on a busy 2-core machine
END_AFTER_CANCEL_S = 30.0
STALE_S = 1.0  # telemetry older than this is not recorded as a sample
AGENT_STOP_S = 10.0
ENDED = ("finished", "failed", "cancelled")


@dataclass
class DemoOptions:
    port: int = 7447
    http_port: int = 8001
    world: Path = DEFAULT_WORLD
    out_dir: Path = Path("demo-out")
    until_done: bool = False
    max_time_s: float = 600.0
    radio: bool = False  # drones on the emulated radio (root): MAVLink vehicles here, agents in namespaces
    mission: Path = SCRIPT  # the script it submits


@dataclass
class _Agent:
    spec: DroneSpec
    proc: subprocess.Popen[bytes]
    log_path: Path
    log_file: IO[bytes]


@dataclass
class _Track:
    telem: Telemetry | None = None
    received: float = 0.0  # monotonic time of the latest telemetry
    sensors: dict[str, Any] = field(default_factory=dict)  # type -> latest value
    state: str = "unknown"  # the ground's view (GET /drone)
    samples: list[dict[str, Any]] = field(default_factory=list)


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    return "\n".join("    " + line for line in text.splitlines()[-lines:])


class Demo:
    """One run of the demo; `run()` returns the exit code (cancellation: see `mission_ok`)."""

    def __init__(self, options: DemoOptions, out: Callable[[str], None]) -> None:
        self.options = options
        self.out = out
        self.endpoint = f"tcp/127.0.0.1:{options.port}"
        # On the radio the agents reach the ground at its radio address: listen on all.
        self.listen = f"tcp/0.0.0.0:{options.port}" if options.radio else self.endpoint
        self.url = f"http://127.0.0.1:{options.http_port}"
        self.keys = Keys()
        self.mission_ok: bool | None = None  # set once the mission has ended
        self.t0 = time.monotonic()
        self.t0_ms = time.time_ns() // 1_000_000
        self.tracks: dict[str, _Track] = {}
        self.agents: list[_Agent] = []
        self.bus: ZenohBus | None = None
        self._tasks: list[asyncio.Task[Any]] = []
        self._broken: asyncio.Future[tuple[str, BaseException | None]] | None = None
        self._stopping = False

    def _draw_map(self) -> Path:
        """The world's field as map tiles in OUT/map.pmtiles (`fleet tiles render`), so the
        dashboard and the planner draw the field under the drones with no tile server."""
        from dronefleet.tiles_cli import write_world_map

        out = self.options.out_dir / "map.pmtiles"
        count = write_world_map(self.options.world, out, MAP_ZOOMS)
        self.out(f"map: {out}, {count} tiles drawn from the world (zooms {MAP_ZOOMS.start}-{MAP_ZOOMS.stop - 1})")
        return out

    # ---- the run ----------------------------------------------------------------------

    async def run(self) -> int:
        if self.options.radio:
            from dronefleet.sim.radio_net import require_net_admin

            require_net_admin()
        world = load_world(self.options.world)
        specs = world.spawn()
        if not specs:
            raise ConfigError(f"{self.options.world}: the world has no drones")
        try:
            source = self.options.mission.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"{exc.filename}: {exc.strerror}") from None
        writable_dir(self.options.out_dir / "logs", "--out")
        self._broken = asyncio.get_running_loop().create_future()
        self.tracks = {spec.id: _Track() for spec in specs}
        self.field_sensors: dict[str, dict[str, Any]] = {}  # result.json's, as heard on the mesh
        with tempfile.TemporaryDirectory(prefix="fleet-demo-") as data_dir:
            # The demo's missions last minutes; its world's heat and gas are not in the copy
            # a preflight flies (the live fleet), so one that searches for them runs to the bound.
            map_file = await asyncio.to_thread(self._draw_map)
            config = GroundConfig(listen=[self.listen], http_port=self.options.http_port, data_dir=data_dir,
                                  mission=MissionSettings(preflight_max_s=DEMO_PREFLIGHT_S),
                                  dashboard=DashboardSettings(tiles=str(map_file)))
            self._background(run_ground(config, self.out), "the ground")
            body: asyncio.Task[int] | None = None
            try:
                async with httpx.AsyncClient(base_url=self.url, timeout=10) as http:
                    body = asyncio.get_running_loop().create_task(self._main(http, world, specs, source), name="demo")
                    either: list[asyncio.Future[Any]] = [body, self._broken]
                    await asyncio.wait(either, return_when=asyncio.FIRST_COMPLETED)
                    if body.done():
                        return body.result()
                    name, failure = self._broken.result()
                    if isinstance(failure, FleetError) and "in use" in str(failure) and not isinstance(failure, ConfigError):
                        raise FleetError(f"{failure} (choose another port with --port)") from None
                    if isinstance(failure, FleetError):
                        raise failure
                    raise FleetError(f"{name} stopped unexpectedly" + (f": {failure!r}" if failure else ""))
            finally:
                cleanup = asyncio.ensure_future(self._stop(body))
                while not cleanup.done():  # a second SIGTERM must not cut the clean-up short
                    with contextlib.suppress(asyncio.CancelledError):
                        await asyncio.shield(cleanup)
                cleanup.result()

    async def _main(self, http: httpx.AsyncClient, world: World, specs: list[DroneSpec], source: str) -> int:
        opts = self.options
        await self._wait_http(http)
        if opts.radio:
            self._start_radio(world)
        else:
            for spec in specs:
                self._start_agent(world, spec)
        self.bus = bus = await ZenohBus.open("client", connect=[self.endpoint], wait=True)
        for spec in specs:
            bus.subscribe(self.keys.telem(spec.id), self._on_telem, latest_only=True)
            bus.subscribe(self.keys.sensor(spec.id), self._on_sensor)
            for kind in spec.sensor_types if not opts.radio else []:  # on the radio: beside each agent
                self._start_sensor(bus, world, spec.id, kind)
        bus.subscribe(self.keys.field_sensor(), self._on_field_sensor)
        for field_sensor in world.field_sensors if not opts.radio else []:  # on the radio: `fleet sim` runs them too
            self._background(world_field_sensor(bus, world, field_sensor, keys=self.keys), f"field sensor {field_sensor.id}")
        sampler = self._background(self._sample(), "the telemetry recorder")

        names = ", ".join(s.id + (f" ({', '.join(s.sensor_types)})" if s.sensors else "") for s in specs)
        self.out("")
        self.out(f"Fleet demo: a ground station and {len(specs)} simulated drones ({names}), world {opts.world}")
        self.out(f"  API:    {self.url}/   (OpenAPI at {self.url}/openapi.json)")
        self.out(f"  Try:    fleet drone list --url {self.url}")
        self.out(f"          fleet mission list --url {self.url}")
        self.out(f"          fleet sub 'drone/**' --connect {self.endpoint}")
        self.out(f"  Agents' logs in {opts.out_dir / 'logs'}")
        self.out("")
        await self._wait_drones(http, specs)

        watched = next((s.id for s in specs if "temperature" in s.sensor_types), specs[0].id)
        gs = world.ground_station or world.origin
        frame = LocalFrame(gs.lat, gs.lon)
        mission_id = await self._submit(http, source)
        record, timed_out = await self._follow(http, mission_id, watched, frame)
        self.mission_ok = record["status"] == "finished" and record.get("cause") == "success"
        self.out(f"{self._stamp()} {outcome(record)}")
        sampler.cancel()
        await asyncio.gather(sampler, return_exceptions=True)
        await self._write_results(http, record, gs.lat, gs.lon)
        if timed_out:
            return 1
        if opts.until_done:
            return 0 if self.mission_ok else 1
        self.out("")
        self.out(f"Ground still up at {self.url}/ — press Ctrl-C to stop")
        while True:
            self._check_agents()
            await asyncio.sleep(1.0)

    # ---- starting and readiness ---------------------------------------------------------

    async def _wait_http(self, http: httpx.AsyncClient) -> None:
        deadline = time.monotonic() + HTTP_READY_S
        while True:
            with contextlib.suppress(httpx.TransportError):
                if (await http.get("/")).status_code == 200:
                    return
            if time.monotonic() > deadline:
                raise FleetError(f"the ground's HTTP API at {self.url} did not answer within {HTTP_READY_S:g} s")
            await asyncio.sleep(0.1)

    def _start_agent(self, world: World, spec: DroneSpec) -> None:
        log_path = self.options.out_dir / "logs" / f"{spec.id}.log"
        log_file = open(log_path, "wb")  # noqa: SIM115 - closed in _stop, after the process ends
        fc = f"sim://?lat={spec.lat!r}&lon={spec.lon!r}&alt={spec.alt!r}"
        proc = subprocess.Popen(
            # three agents share this host: each router on its own ephemeral loopback port
            agent_command(spec.id, fc, connect=[self.endpoint], listen=["tcp/127.0.0.1:0"],
                          telemetry_rate_ms=TELEMETRY_RATE_MS, state_dir=self.options.out_dir / "state" / spec.id,
                          config=drone_agent_config(None, world, spec, self.options.out_dir / "state"),
                          kind=spec.kind, roles=spec.roles or ()),
            stdin=subprocess.DEVNULL, stdout=log_file, stderr=subprocess.STDOUT,
        )
        self.agents.append(_Agent(spec, proc, log_path, log_file))

    def _start_radio(self, world: World) -> None:
        """`fleet sim --agents --radio` in the background: the vehicles here, each drone's
        agent and sensors in its own namespace, loss following the distances. Its
        lines go to logs/sim.log, the radio's own to the screen."""
        from dronefleet.sim.autopilot_params import BRISK_PX4
        from dronefleet.sim.fleet_sim import autopilot_of, run_sim

        logs = self.options.out_dir / "logs"
        agent_config = logs / "agent.yml"
        agent_config.write_text(f"telemetry_rate_ms: {TELEMETRY_RATE_MS}\n")
        sim_log = open(logs / "sim.log", "a", encoding="utf-8")  # noqa: SIM115 - closed with the task

        def out(line: str) -> None:
            if line.startswith("radio:"):
                self.out(f"{self._stamp()} {line}")
            sim_log.write(line + "\n")
            sim_log.flush()

        task = self._background(
            run_sim(world, None, agents=True, radio=True, ground_port=self.options.port, agent_config=agent_config,
                    out=out, log_dir=logs,
                    # The radio demo flies its PX4 vehicles briskly: at PX4's own start,
                    # acceleration and landing times (fleet sim's default) its fire trace of
                    # short legs takes four times as long.
                    params=BRISK_PX4 if "px4" in autopilot_of(world.spawn(), None).values() else None),
            "the emulated radio",
        )
        task.add_done_callback(lambda _: sim_log.close())

    def _start_sensor(self, bus: Bus, world: World, drone_id: str, kind: str) -> None:
        self._background(simulated_sensor(bus, drone_id, kind, world, keys=self.keys), f"the {kind} sensor of {drone_id}")

    async def _wait_drones(self, http: httpx.AsyncClient, specs: list[DroneSpec]) -> None:
        self.out(f"{self._stamp()} waiting for {len(specs)} drones to be ready with their sensors")
        deadline = time.monotonic() + DRONES_READY_S
        while True:
            self._check_agents()
            infos = await self._poll_states(http)
            missing = [  # ready, with its sensors, and healthy (an autopilot's checks pass after its start)
                s.id for s in specs
                if s.id not in infos or infos[s.id]["state"] != "ready" or not set(s.sensor_types) <= set(infos[s.id]["sensors"])
                or infos[s.id].get("errors")
            ]
            if not missing:
                self.out(f"{self._stamp()} all drones ready: {', '.join(s.id for s in specs)}")
                return
            if time.monotonic() > deadline:
                detail = "; ".join(
                    f"{d}: " + (f"{infos[d]['state']}, sensors {infos[d]['sensors']}"
                                + "".join(f", {e}" for e in infos[d].get("errors") or []) if d in infos else "not registered")
                    for d in missing
                )
                raise FleetError(f"drones not ready within {DRONES_READY_S:g} s ({detail}); see {self.options.out_dir / 'logs'}")
            await asyncio.sleep(0.2)

    async def _poll_states(self, http: httpx.AsyncClient) -> dict[str, dict[str, Any]]:
        response = await http.get("/drone", params={"data": "info"})
        response.raise_for_status()
        infos = {view["info"]["drone_id"]: view["info"] for view in response.json()}
        for drone_id, info in infos.items():
            if drone_id in self.tracks:
                self.tracks[drone_id].state = info["state"]
        return infos

    def _check_agents(self) -> None:
        for agent in self.agents:
            code = agent.proc.poll()
            if code is not None:
                raise FleetError(
                    f"the agent of {agent.spec.id} exited (code {code}); the end of {agent.log_path}:\n{_tail(agent.log_path)}"
                )

    # ---- the mission ---------------------------------------------------------------------

    async def _submit(self, http: httpx.AsyncClient, source: str) -> str:
        name = self.options.mission.name
        self.out(f"{self._stamp()} preflight: the ground flies {name} in fast time against these drones first")
        response = await http.post("/mission", content=source.encode(), params={"name": name}, timeout=PREFLIGHT_WAIT_S)
        if response.status_code != 201:
            raise FleetError(f"the ground refused {name}: {response.status_code} {response.text}")
        created = response.json()
        mission_id = str(created["mission_id"])
        if created.get("preflight"):
            self.out(f"{self._stamp()} {preflight_summary(created['preflight'])}")
        self.out(f"{self._stamp()} mission {mission_id} submitted: {name}"
                 f" (follow it: fleet mission show {mission_id} --url {self.url})")
        return mission_id

    async def _follow(self, http: httpx.AsyncClient, mission_id: str, watched: str,
                      frame: LocalFrame) -> tuple[dict[str, Any], bool]:
        """Print the mission's log lines and a status line every few seconds until it ends."""
        started = time.monotonic()
        next_status = started + STATUS_EVERY_S
        cancelled_at: float | None = None
        seen = 0
        while True:
            response = await http.get(f"/mission/{mission_id}")
            response.raise_for_status()
            record = response.json()
            for line in record["log"][seen:]:
                level = "" if line["level"] == "info" else line["level"].upper() + " "
                self.out(f"{self._stamp(line['timestamp'])} {level}{line['message']}")
            seen = len(record["log"])
            if record["status"] in ENDED and record.get("end") is not None:
                record.pop("log", None)
                return record, cancelled_at is not None
            await self._poll_states(http)
            now = time.monotonic()
            if now >= next_status:
                self.out(self._status_line(watched, frame))
                next_status += STATUS_EVERY_S * max(1, math.ceil((now - next_status) / STATUS_EVERY_S))
            if cancelled_at is None and now - started > self.options.max_time_s:
                self.out(f"{self._stamp()} the mission ran longer than --max-time {self.options.max_time_s:g} s: cancelling it")
                await http.delete(f"/mission/{mission_id}")
                cancelled_at = now
            elif cancelled_at is not None and now - cancelled_at > END_AFTER_CANCEL_S:
                raise FleetError(f"mission {mission_id} did not end within {END_AFTER_CANCEL_S:g} s of its cancellation")
            self._check_agents()
            await asyncio.sleep(POLL_S)

    def _status_line(self, drone_id: str, frame: LocalFrame) -> str:
        track = self.tracks[drone_id]
        t = track.telem
        if t is None or t.position is None or time.monotonic() - track.received > 3 * STALE_S:
            return f"{self._stamp()} {drone_id}: no telemetry"
        north, east = frame.to_local(t.position.lat, t.position.lon)
        temp = track.sensors.get("temperature")
        parts = [
            f"{drone_id} {track.state:<6}",
            f"{abs(north):5.1f} m {'N' if north >= 0 else 'S'} {abs(east):5.1f} m {'E' if east >= 0 else 'W'} of the ground",
            f"alt {t.position.rel_alt:4.1f} m",
        ]
        if isinstance(temp, (int, float)):
            parts.append(f"{temp:4.1f} °C")
        if t.battery is not None:
            parts.append(f"battery {t.battery.remaining_percent:.0%}")
        return f"{self._stamp()} " + " | ".join(parts)

    # ---- recording -------------------------------------------------------------------------

    def _on_telem(self, sample: Sample) -> None:
        try:
            t = decode_telemetry(sample.payload)
        except Exception:  # noqa: BLE001 - a bad sample is not recorded; the ground logs such things
            return
        track = self.tracks.get(t.drone_id)
        if track is not None:
            track.telem = t
            track.received = time.monotonic()

    def _on_sensor(self, sample: Sample) -> None:
        try:
            reading = decode_sensor(sample.payload)
        except Exception:  # noqa: BLE001
            return
        track = self.tracks.get(reading.drone_id)
        if track is not None:
            track.sensors[reading.type] = reading.data

    def _on_field_sensor(self, sample: Sample) -> None:
        try:
            reading = decode_sensor(sample.payload)
        except Exception:  # noqa: BLE001
            return
        add_field_reading(self.field_sensors, reading, time.monotonic() - self.t0)

    async def _sample(self) -> None:
        """Every drone's latest telemetry at the same instants (so the plots can pair them)."""
        period = TELEMETRY_RATE_MS / 1000
        k = 0
        while True:
            k = max(k + 1, math.floor((time.monotonic() - self.t0) / period))
            await asyncio.sleep(max(0.0, self.t0 + k * period - time.monotonic()))
            now = time.monotonic()
            for track in self.tracks.values():
                t = track.telem
                if t is None or t.position is None or now - track.received > STALE_S:
                    continue
                track.samples.append(telemetry_sample(t, k * period, track.state, dict(track.sensors)))

    async def _write_results(self, http: httpx.AsyncClient, record: dict[str, Any], gs_lat: float, gs_lon: float) -> None:
        from dronefleet.mission.hosting.plots import write_plots
        from dronefleet.mission.hosting.simulate import write_result

        out_dir = self.options.out_dir
        response = await http.get(f"/mission/{record['mission_id']}")
        log_lines = response.json().get("log", []) if response.status_code == 200 else []
        result = {
            "mission": record,
            "log": log_lines,
            "world": str(self.options.world),
            "t0_ms": self.t0_ms,  # wall time of t_s = 0
            "ground_station": {"lat": gs_lat, "lon": gs_lon},
            "drones": {
                drone_id: {"samples": track.samples, "commands": []} for drone_id, track in sorted(self.tracks.items())
            },
            **({"field_sensors": self.field_sensors} if self.field_sensors else {}),
        }
        write_result(result, out_dir, plots=False)  # the one writer of result.json (fast time's too)
        events = await http.get("/drone/logs")
        if events.status_code == 200:
            (out_dir / "ground.log").write_text(events.text)
        plots = await asyncio.to_thread(write_plots, result, out_dir)  # matplotlib is slow: keep the ground serving
        self.out(f"{self._stamp()} wrote {out_dir / 'result.json'}, {out_dir / 'ground.log'} and plots "
                 f"({', '.join(p.name for p in plots)}) in {out_dir}")

    # ---- background tasks and stopping -----------------------------------------------------

    def _background(self, coro: Coroutine[Any, Any, Any], name: str) -> asyncio.Task[Any]:
        task = asyncio.get_running_loop().create_task(coro, name=name)
        self._tasks.append(task)
        task.add_done_callback(self._ended)
        return task

    def _ended(self, task: asyncio.Task[Any]) -> None:
        if self._stopping or task.cancelled() or self._broken is None or self._broken.done():
            return
        self._broken.set_result((task.get_name(), task.exception()))

    async def _stop(self, body: asyncio.Task[int] | None) -> None:
        """Agents first told to stop (no await before), then everything in reverse order of start."""
        self._stopping = True
        if not logging.getLogger().isEnabledFor(logging.DEBUG):  # drones leaving (and a mission failing) is expected now
            for name in ("dronefleet.ground", "dronefleet.mission"):
                logging.getLogger(name).setLevel(logging.CRITICAL)
        for agent in self.agents:
            if agent.proc.poll() is None:
                agent.proc.terminate()
        if body is not None and not body.done():
            body.cancel()
        ground, rest = self._tasks[0], self._tasks[1:]
        for task in rest:
            task.cancel()
        await asyncio.gather(*([body] if body is not None else []), *rest, return_exceptions=True)
        deadline = time.monotonic() + AGENT_STOP_S
        for agent in self.agents:  # they stop with the ground's liveliness or their own SIGTERM
            with contextlib.suppress(subprocess.TimeoutExpired):
                await asyncio.to_thread(agent.proc.wait, max(0.0, deadline - time.monotonic()))
        for agent in self.agents:
            if agent.proc.poll() is None:
                agent.proc.kill()
                agent.proc.wait()
            agent.log_file.close()
        if self.bus is not None:
            await self.bus.close()
        ground.cancel()
        await asyncio.gather(ground, return_exceptions=True)
        if self.agents:
            self.out(f"{self._stamp()} demo stopped: agents, sensors and ground")

    def _stamp(self, at_ms: int | None = None) -> str:
        seconds = (at_ms - self.t0_ms) / 1000 if at_ms is not None else time.monotonic() - self.t0
        return f"[{seconds:6.1f} s]"

