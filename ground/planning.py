"""Planning on the map (SPEC §10): a script checked as it is written, *simulated* in fast
time against a world made from the live fleet, and waypoints exported as a
QGroundControl plan (SPEC §13).

The prediction runs `fleet mission simulate` in a child process: fast time is a busy
loop under a virtual clock, which would stall the ground's own event loop (telemetry,
commands, the flying missions) if it ran there. The world is the fleet as the ground
knows it: each drone with a position where it is (on the ground, at its home's
altitude), its battery, kind, roles and sensor types; the ground's geofence; no radio
(the prediction is of the plan, not of the field's links).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import msgspec
from msgspec import Meta

from dronefleet.mission.hosting.simulate import SimResult, UnknownRead
from dronefleet.schemas.about import Role, SensorDeclaration
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.telemetry import SensorReading
from dronefleet.sim.world import Autopilot, BatteryModel, DroneSpec, FieldSensorSpec, Spot, World
from dronefleet.sim.world_fields import FieldModel

log = logging.getLogger(__name__)
SIMULATION_WALL_S = 180.0  # a prediction that takes longer on this machine is stopped
# The wall bound counts from the simulation's start, which the child says (SIMULATING):
# as one of eight suite workers starting at once, a 10 s bound left it 1.1 s simulated,
# and a busy laptop's preflight passed unjudged so. A child that does not get that far in
# START_WALL_S is stopped, as at the bound.
SIMULATING = b"simulating\n"
START_WALL_S = 60.0
PATH_POINTS = 600  # per drone at most: the map draws them, the chart the battery
ROLES = frozenset(get_args(Role))
AUTOPILOT_MAKES = frozenset(get_args(Autopilot))  # flown with their own timing (sim/autopilot_params.py)
DEFAULT_TEMP_C = World().environment_temp  # the world's, where no temperature was heard


class _Body(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


class SimulateBody(_Body, frozen=True):
    source: str
    max_s: Annotated[float, Meta(ge=10, le=7200)] = 1800.0  # simulated seconds before it is cancelled


class PlanWaypoint(_Body, frozen=True):
    lat: Annotated[float, Meta(ge=-90, le=90)]
    lon: Annotated[float, Meta(ge=-180, le=180)]
    alt: Annotated[float, Meta(ge=0, le=1000)]  # m above home
    hold_s: Annotated[float, Meta(ge=0, le=3600)] = 0.0
    speed: Annotated[float, Meta(gt=0, le=30)] | None = None


class ExportBody(_Body, frozen=True):
    waypoints: Annotated[list[PlanWaypoint], Meta(min_length=1)]
    home: Annotated[list[float], Meta(min_length=3, max_length=3)]  # lat, lon, alt AMSL
    takeoff_alt: Annotated[float, Meta(gt=0, le=1000)] = 10.0
    end: Literal["land", "return", "hold"] = "land"


class PredictedDrone(msgspec.Struct, frozen=True, kw_only=True):
    path: list[tuple[float, float, float, float]]  # (t_s, lat, lon, rel_alt), at most PATH_POINTS
    battery: list[tuple[float, float]]  # (t_s, 0..1)
    battery_start: float | None
    battery_end: float | None
    flying_s: float  # time armed and off the ground


class Prediction(msgspec.Struct, frozen=True, kw_only=True):
    status: str
    cause: str | None
    message: str
    line: int | None = None  # the script's line an error ended it at
    duration_s: float  # simulated, from start to end of the mission
    wall_s: float
    drones: dict[str, PredictedDrone]  # the drones the mission used
    log: list[str]
    # The first line that read what the world, a copy of the live fleet, cannot know
    # (a sensor, the field sensors, the radio): what follows it is a guess
    unknown: UnknownRead | None = None


def decode_body(body: bytes, kind: type[Any], what: str) -> Any:
    """A JSON body as `kind`, or InvalidMessage naming the field at fault."""
    try:
        return msgspec.json.decode(body, type=kind)
    except msgspec.ValidationError as exc:
        at = re.search(r"at `(\$[^`]*)`", str(exc))
        raise InvalidMessage(f"{what}: {str(exc).replace('$.', '')}", field=at.group(1) if at else None) from None
    except msgspec.DecodeError as exc:
        raise InvalidMessage(f"{what}: not JSON: {exc}") from None


def live_world(drones: list[tuple[Any, Any]], geofence: Any, ground: tuple[float, float] | None,
               drain_per_s: float = BatteryModel().drain_per_s, readings: Sequence[SensorReading] = (),
               field_sensors: Sequence[Any] = ()) -> World:
    """The world of a prediction from (DroneInfo, Telemetry) pairs: drones without a
    position are left out (nothing to fly from). Batteries drain `drain_per_s` in flight
    down to empty (no floor: a real pack runs out). Sensors read what the ground last
    heard of their type (`readings`, the drones' and the field sensors'), everywhere:
    each field as a field of that value, a temperature as the environment's; what
    was never heard is not invented. A mission's read of any of them is what the
    prediction cannot know (`Prediction.unknown`): a guess from there on. Field
    sensors (FieldSensorInfo) with a position stand where they are, with the types of
    theirs the world can read."""
    fields, temperature = _last_fields(readings)
    specs = []
    for info, telem in drones:
        pos = telem.position if telem is not None else None
        if pos is None:
            continue
        ground_alt = telem.home.alt if telem.home is not None else pos.alt - pos.rel_alt
        battery = telem.battery.remaining_percent if telem.battery is not None else None
        roles = [r for r in (info.roles or []) if r in ROLES]
        # The sensors the ground has heard from (a mission assigns by those), as declared,
        # and those declared but not heard yet (their readings are unknown: never invented)
        declared = {d.type: d for d in getattr(info, "sensors_declared", None) or []}
        sensors: list[str | SensorDeclaration] = [declared.get(t, t) for t in info.sensors]
        sensors += [d for t, d in declared.items() if t not in info.sensors]
        make = getattr(info, "autopilot", None)
        specs.append(DroneSpec(id=info.drone_id, lat=pos.lat, lon=pos.lon, alt=ground_alt,
                               sensors=sensors, kind=info.kind, roles=roles or None,
                               autopilot=make if make in AUTOPILOT_MAKES else None,
                               battery=None if battery is None else min(1.0, max(0.0, battery))))
    if not specs:
        raise InvalidMessage("no drone with a position to simulate: the ground has heard none yet")
    standing = [FieldSensorSpec(id=f.sensor_id, type=t, lat=f.position.lat, lon=f.position.lon, alt=f.position.alt)
                for f in field_sensors if f.position is not None
                for t in f.types if t in fields or (t == "temperature" and temperature is not None)]
    origin = Spot(lat=specs[0].lat or 0.0, lon=specs[0].lon or 0.0, alt=specs[0].alt or 0.0)
    station = Spot(lat=ground[0], lon=ground[1]) if ground else None
    fence = geofence if geofence is not None and (geofence.polygon or geofence.max_alt_m is not None) else None
    return World(origin=origin, ground_station=station, drones=specs, geofence=fence, fields=fields,
                 field_sensors=standing, environment_temp=DEFAULT_TEMP_C if temperature is None else temperature,
                 battery=BatteryModel(drain_per_s=drain_per_s, floor=0.0))


def _last_fields(readings: Sequence[SensorReading]) -> tuple[dict[str, dict[str, FieldModel]], float | None]:
    """Per sensor type, each field at its latest value (a number, a word or a flag as it
    came; a field that came empty is left unknown); the latest temperature."""
    fields: dict[str, dict[str, FieldModel]] = {}
    temperature: float | None = None
    for reading in sorted(readings, key=lambda r: r.timestamp):
        if reading.fields:
            values = {k: FieldModel(background=float(v) if isinstance(v, int) and not isinstance(v, bool) else v)
                      for k, v in reading.fields.items() if v is not None}
            if values:
                fields[reading.type] = {**fields.get(reading.type, {}), **values}
        elif reading.type == "temperature" and isinstance(reading.value, int | float) and not isinstance(reading.value, bool):
            temperature = float(reading.value)
    return fields, temperature


def prediction_of(result: SimResult, wall_s: float, log_lines: list[str]) -> Prediction:
    """What the map and the chart draw, from `fleet mission simulate`'s result.json."""
    record = result.mission
    duration = ((record.end or 0) - (record.start or 0)) / 1000
    drones = {}
    for drone_id in record.used_drones or list(result.drones):
        track = result.drones.get(drone_id)
        samples = track.samples if track is not None else []
        step = max(1, -(-len(samples) // PATH_POINTS))
        picked = samples[::step] + ([samples[-1]] if samples and (len(samples) - 1) % step else [])
        flying = [s for s in samples if s.armed and s.rel_alt > 0.5]
        charge = [s.battery for s in samples if s.battery is not None]
        period = samples[1].t_s - samples[0].t_s if len(samples) > 1 else 0.0
        drones[drone_id] = PredictedDrone(
            path=[(s.t_s, s.lat, s.lon, s.rel_alt) for s in picked],
            battery=[(s.t_s, s.battery) for s in picked if s.battery is not None],
            battery_start=samples[0].battery if samples else None,
            # the least it held: a simulated drone that lands and disarms gets a fresh pack
            battery_end=min(charge, default=None),
            flying_s=round(len(flying) * period, 1),
        )
    return Prediction(status=record.status, cause=record.cause, message=record.message or "", line=record.line,
                      duration_s=round(duration, 1), wall_s=round(wall_s, 2), drones=drones, log=log_lines[-200:],
                      unknown=result.unknown)


@dataclass(frozen=True)
class Bounds:
    """What one prediction's child process may take: wall seconds on the ground's machine,
    and, as a mission's sandbox, memory beyond its own and CPU seconds."""

    wall_s: float = SIMULATION_WALL_S
    memory_mb: int | None = None
    cpu_s: float | None = None


class SimulationBound(Exception):
    """The wall bound ended a simulation before the mission did: `line` is the script's
    line it was computing at then (None: the simulation itself was still flying),
    `simulated_s` how far it got."""

    def __init__(self, wall_s: float, line: int | None, simulated_s: float | None) -> None:
        self.wall_s, self.line, self.simulated_s = wall_s, line, simulated_s
        where = f"still computing at line {line} of the script" if line is not None else "still flying"
        reached = f", {simulated_s:g} s simulated" if simulated_s is not None else ""
        super().__init__(f"the simulation was {where} when its bound of {wall_s:g} s on the ground's machine "
                         f"ended it{reached}")


_SCRIPT_FRAME = re.compile(r'File "<mission [^>]*>", line (\d+)')
_ECHOED_T = re.compile(r"^\[\s*([0-9.]+) s\]")
DUMP_WAIT_S = 1.0  # for the child's stack dumps after SIGUSR1
DUMPS = 5  # spread over DUMP_WAIT_S


async def _line_computing(proc: asyncio.subprocess.Process, out: bytearray, reading: asyncio.Task[None]) -> int | None:
    """The script's line the child is computing at, from its stack dumps (SIGUSR1), or
    None if no dump shows one. A script that never waits still yields to the loop at
    every slice (mission/lifecycle/greenlets.py), and a dump taken then shows no script
    frame: so up to DUMPS dumps, until one shows a line. A script waiting on its drones
    shows none in any."""
    for _ in range(DUMPS):
        start = len(out)
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGUSR1)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.shield(reading), DUMP_WAIT_S / DUMPS)
        line = _stuck_line(out[start:].decode("utf-8", "replace"))
        if line is not None or reading.done():
            return line
    return None


def _stuck_line(output: str) -> int | None:
    """The script's innermost line in the stacks the child dumped, if the script was on
    one (a script waiting on its drones is on none: its frames are suspended)."""
    start = output.find("(most recent call first):")
    found = _SCRIPT_FRAME.search(output, start) if start >= 0 else None
    return int(found.group(1)) if found else None


def _simulated_s(lines: list[str]) -> float | None:
    for line in reversed(lines):
        found = _ECHOED_T.match(line)
        if found:
            return float(found.group(1))
    return None


async def predict(source: str, world: World, max_s: float, plugins_dir: Path | None = None,
                  bounds: Bounds = Bounds()) -> Prediction:
    """Run `fleet mission simulate` on `source` in `world` in a child process, with the
    bundled plugins and those in `plugins_dir`, within `bounds` (SimulationBound past
    its wall time; a memory or CPU limit ends the mission as the sandbox does)."""
    import yaml

    with tempfile.TemporaryDirectory(prefix="fleet-predict-") as tmp:
        d = Path(tmp)
        (d / "plan.py").write_text(source, encoding="utf-8")
        (d / "world.yml").write_text(yaml.safe_dump(msgspec.to_builtins(world)), encoding="utf-8")
        args = [sys.executable, "-m", "dronefleet", "mission", "simulate", str(d / "plan.py"), "--world", str(d / "world.yml"),
                "--out", str(d / "out"), "--max-time", str(max_s), "--no-plots", "--predicting",
                *(["--plugins-dir", str(plugins_dir)] if plugins_dir is not None else []),
                *(["--limit-memory-mb", str(bounds.memory_mb)] if bounds.memory_mb is not None else []),
                *(["--limit-cpu-s", str(bounds.cpu_s)] if bounds.cpu_s is not None else [])]
        started = time.monotonic()
        proc = await asyncio.create_subprocess_exec(*args, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
                                                    stderr=asyncio.subprocess.STDOUT)
        out = bytearray()
        simulating = asyncio.Event()

        async def read() -> None:
            assert proc.stdout is not None
            while chunk := await proc.stdout.read(65536):
                out.extend(chunk)
                if not simulating.is_set() and (out.startswith(SIMULATING) or b"\n" + SIMULATING in out):
                    simulating.set()
            simulating.set()  # it ended (or closed its output) before saying so

        reading = asyncio.get_running_loop().create_task(read())
        try:
            try:
                await asyncio.wait_for(simulating.wait(), START_WALL_S)
                await asyncio.wait_for(proc.wait(), bounds.wall_s)
            except TimeoutError:
                line = await _line_computing(proc, out, reading)
                text = out.decode("utf-8", "replace")
                raise SimulationBound(bounds.wall_s, line, _simulated_s(text.splitlines())) from None
            await reading
        finally:  # the bound, or the client went: so does the child
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            reading.cancel()
        lines = [line for line in out.decode("utf-8", "replace").splitlines() if line != SIMULATING.decode().strip()]
        result_file = d / "out" / "result.json"
        if not result_file.exists():  # it did not get to run the mission: say why
            if proc.returncode == -signal.SIGXCPU:
                raise InvalidMessage(f"the simulation used more than its {bounds.cpu_s:g} s of CPU")
            raise InvalidMessage("the simulation did not run: " + (" / ".join(lines[-3:]) or f"exit {proc.returncode}"))
        result = msgspec.json.decode(result_file.read_bytes(), type=SimResult)
        return prediction_of(result, time.monotonic() - started, lines)
