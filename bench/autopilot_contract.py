"""The agent's flight contract (SPEC §2–§3, §8) flown against a MAVLink autopilot, as a
user flies it: `fleet agent` on its key space, one command after another over real
Zenoh, the autopilot's own parameters. Prints the pass rate of every step over N runs
and exits 1 on any failure.

    .venv/bin/python bench/autopilot_contract.py --autopilot sim-px4 --runs 20
    .venv/bin/python bench/autopilot_contract.py --autopilot sim-ardupilot --runs 20
    FLEET_PX4_BUILD=~/PX4-Autopilot/build/px4_sitl_default \\
        .venv/bin/python bench/autopilot_contract.py --autopilot px4 --runs 20
    FLEET_ARDUCOPTER=~/ardupilot/build/sitl/bin/arducopter \\
        .venv/bin/python bench/autopilot_contract.py --autopilot arducopter --runs 20
    .venv/bin/python bench/autopilot_contract.py --fc udpin://0.0.0.0:14540 --runs 1   # one already running

Each run starts the autopilot afresh (`fleet sim -n 1` in the personality named, or the
real SITL: PX4's SIH quadrotor from a build folder, ArduCopter's `arducopter` binary,
parameters wiped), a router playing the ground, and `fleet agent --fc …`. With `--fc`
the autopilot is the caller's and is not restarted: the runs fly one after another.
A step that fails ends its run; the steps after it count as not reached.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import signal
import statistics
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from contextlib import AsyncExitStack
from dataclasses import dataclass, field
from pathlib import Path

import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.geo import angle_diff_deg, bearing_deg, destination, distance_m  # noqa: E402
from dronefleet.schemas.status import CommandStatus, SystemStatus  # noqa: E402
from dronefleet.schemas.telemetry import Position, Telemetry  # noqa: E402
from tests.harness import AgentProcess, ChildProcess, Operator, SimProcess, open_ground_router  # noqa: E402
from tests.ports import free_port, free_udp_base  # noqa: E402

TELEMETRY_FIELDS = {
    "drone_id", "timestamp", "seq", "armed", "battery", "flight_mode", "gps_info", "heading",
    "health_failures", "home", "landed_state", "position", "velocity", "speed",
}
NESTED = {
    "battery": {"remaining_percent", "voltage"},
    "gps_info": {"satellites", "fix_type"},
    "home": {"lat", "lon", "alt"},
    "position": {"lat", "lon", "alt", "rel_alt"},
    "velocity": {"north", "east", "down"},
}
# Real autopilots hover within about a metre (PX4's SIH GPS noise, shared/notes/px4-facts.md):
# the agent's acceptance radius and the bench's tolerances allow for it.
ACCEPTANCE_RADIUS_M = 1.0
TAKEOFF_ALT_M = 8.0
TAKEOFF_TOLERANCE_M = 2.0
LOST_LINK = {"timeout_s": 2, "action": "hold", "return_after_s": 4}
# The agent's own limits on a default-parameter flight: PX4 lands at 0.7 m/s below
# 10 m (MPC_LAND_SPEED), ArduCopter at 0.5 m/s (LAND_SPEED).
LANDING_S = 90
READY_S = 120  # ArduCopter SITL reaches health_all_ok about 42 s after launch; PX4 5.5 s


class StepFailed(AssertionError):
    pass


def check(ok: object, what: str) -> None:
    if not ok:
        raise StepFailed(what)


def at(t: Telemetry) -> Position:
    check(t.position is not None, "telemetry without a position")
    assert t.position is not None
    return t.position


@dataclass
class Flight:
    """One run's operator and what the steps learn on the way."""

    op: Operator
    ground: ZenohBus | None  # closed by the lost-link step
    armed_home: Position | None = None  # where the last arming was
    notes: list[str] = field(default_factory=list)

    async def expect(self, command_id: str, state: str, timeout_s: float = 30) -> CommandStatus:
        status = await self.op.command_state(command_id, state, timeout_s)
        check(status.state == state, f"{command_id}: expected {state}, got {status.state} ({status.reason})")
        return status

    async def accepted(self, cmd: str, **fields: object) -> str:
        reply = await self.op.send(cmd, **fields)
        check(reply.accepted, f"{cmd} {fields} refused: {reply.reason}")
        return reply.command_id

    async def settle(self) -> Telemetry:
        """A sample taken once the drone holds still: under 0.5 m/s across and 0.3 m/s up
        or down, in two samples a second apart (a real autopilot's hover wanders)."""
        first = await self.op.next_telemetry(still, 30, "holding still")
        last = await self.op.next_telemetry(lambda t: still(t) and t.timestamp >= first.timestamp + 1000, 30,
                                            "holding still a second later")
        second = [at(t) for t in self.op.telem.items if first.timestamp <= t.timestamp <= last.timestamp]
        # the median of a second's positions: PX4's SIH altitude jumps a metre or more in single samples
        middle = Position(**{k: statistics.median(getattr(p, k) for p in second) for k in ("lat", "lon", "alt", "rel_alt")})
        return msgspec.structs.replace(last, position=middle)

    async def arm(self) -> None:
        await self.expect(await self.accepted("arm"), "success")
        t = await self.op.next_telemetry(lambda t: t.armed and t.home is not None, 10, "armed in telemetry")
        self.armed_home = at(t)  # PX4 and ArduCopter set home at every arming, where the drone is


def still(t: Telemetry) -> bool:
    return t.speed < 0.5 and abs(t.velocity.down) < 0.3


async def step_telemetry(f: Flight) -> None:
    """Every SPEC field, at the configured 100 ms (median interval), seq without gaps."""
    op = f.op
    await op.next_telemetry(lambda t: all(getattr(t, k) is not None for k in NESTED), READY_S,
                            "telemetry with every field known")
    await op.next_telemetry(lambda t: not t.health_failures, READY_S, "a healthy autopilot")
    for _ in range(21):
        await op.next_telemetry(timeout_s=5)
    raw = json.loads(op.raw_telem[-1])
    check(set(raw) == TELEMETRY_FIELDS, f"telemetry fields {sorted(raw)}")
    for key, fields in NESTED.items():
        check(set(raw[key]) == fields, f"telemetry {key} fields {sorted(raw[key])}")
    last = op.telem.items[-21:]
    intervals = [b.timestamp - a.timestamp for a, b in zip(last, last[1:], strict=False)]
    check(80 <= statistics.median(intervals) <= 130, f"telemetry intervals {intervals}")
    check([t.seq for t in last] == list(range(last[0].seq, last[0].seq + 21)), "telemetry seq with gaps")


async def step_refusals(f: Flight) -> None:
    """Disarmed, everything but arm and return is refused with the reason."""
    for cmd, fields in (("takeoff", {"alt": 5}), ("land", {}), ("turn", {"deg": 90}), ("move", {"y": 5})):
        reply = await f.op.send(cmd, **fields)
        check(not reply.accepted and reply.reason == "disarmed", f"{cmd} while disarmed: {reply}")
        await f.expect(reply.command_id, "failure", 10)
    here = at(f.op.last)
    reply = await f.op.send("goto", lat=here.lat, lon=here.lon)
    check(not reply.accepted and reply.reason == "disarmed", f"goto while disarmed: {reply}")


async def step_arm(f: Flight) -> None:
    await f.arm()


async def step_takeoff(f: Flight) -> None:
    takeoff = await f.accepted("takeoff", alt=TAKEOFF_ALT_M)
    start = await f.expect(takeoff, "start", 10)
    check(getattr(start, "altitude", None) == TAKEOFF_ALT_M, f"takeoff start {start}")
    await f.expect(takeoff, "finish", 60)
    t = await f.settle()
    # PX4 SIH's altitude above home carries an offset of up to 1.5 m from the arming on,
    # besides its jumps (its takeoff to 8 m reads 6.3-7.5 m in some runs): 2 m allowed
    check(abs(at(t).rel_alt - TAKEOFF_ALT_M) <= TAKEOFF_TOLERANCE_M, f"took off to {at(t).rel_alt:.1f} m")


async def step_goto(f: Flight) -> None:
    """30 m north, yaw null (face the target), no alt (keep the altitude)."""
    t = await f.settle()
    alt = at(t).alt
    lat, lon = destination(at(t).lat, at(t).lon, 30, 0)
    goto = await f.accepted("goto", lat=lat, lon=lon, yaw=None)
    start = await f.expect(goto, "start", 10)
    coords = getattr(start, "coords", None)
    check(coords is not None and abs(coords.alt - alt) < 0.5, f"goto start {start}")
    await f.expect(goto, "finish", 60)
    t = await f.settle()
    check(distance_m(at(t).lat, at(t).lon, lat, lon) <= ACCEPTANCE_RADIUS_M + 1, "goto ended away from its target")
    check(abs(angle_diff_deg(t.heading, 0)) < 5, f"heading {t.heading:.0f}°, not north")
    check(abs(at(t).alt - alt) < 1.5, f"altitude {at(t).alt:.1f}, was {alt:.1f}")


async def step_goto_yaw_alt(f: Flight) -> None:
    """20 m east, facing south, 4 m higher."""
    t = await f.settle()
    lat, lon = destination(at(t).lat, at(t).lon, 20, 90)
    alt = at(t).alt + 4
    goto = await f.accepted("goto", lat=lat, lon=lon, alt=alt, yaw=180)
    await f.expect(goto, "finish", 60)
    t = await f.op.next_telemetry(lambda t: abs(angle_diff_deg(t.heading, 180)) < 5, 20, "facing south")
    check(distance_m(at(t).lat, at(t).lon, lat, lon) <= ACCEPTANCE_RADIUS_M + 1, "goto ended away from its target")
    check(abs(at(t).alt - alt) < 1.5, f"altitude {at(t).alt:.1f}, not {alt:.1f}")


async def step_turn(f: Flight) -> None:
    before = (await f.settle()).heading
    finish = await f.expect(await f.accepted("turn", deg=90), "finish", 30)
    t = await f.op.next_telemetry(lambda t: t.timestamp > finish.timestamp, 5, "telemetry after the turn")
    check(abs(angle_diff_deg(t.heading, before + 90)) < 5, f"heading {t.heading:.0f}°, not {before + 90:.0f}°")


async def step_move(f: Flight) -> None:
    """10 m to the right of the heading."""
    t = await f.settle()
    before, heading = at(t), t.heading
    await f.expect(await f.accepted("move", x=10), "finish", 40)
    t = await f.settle()
    moved = distance_m(before.lat, before.lon, at(t).lat, at(t).lon)
    check(abs(moved - 10) <= ACCEPTANCE_RADIUS_M + 1, f"moved {moved:.1f} m")
    way = bearing_deg(before.lat, before.lon, at(t).lat, at(t).lon)
    check(abs(angle_diff_deg(way, heading + 90)) < 10, f"moved towards {way:.0f}°, heading {heading:.0f}°")


async def step_cancel(f: Flight) -> None:
    """A goto 300 m west, cancelled in flight: the drone holds."""
    here = at(await f.settle())
    lat, lon = destination(here.lat, here.lon, 300, 270)
    far = await f.accepted("goto", lat=lat, lon=lon, yaw=None)
    await f.expect(far, "start", 10)
    await f.op.next_telemetry(lambda t: t.speed > 1, 30, "flying west")
    cancel = await f.accepted("cancel")
    await f.expect(far, "cancel", 10)
    await f.expect(cancel, "success", 10)
    await f.op.next_telemetry(still, 30, "holding after the cancel")


async def step_land(f: Flight) -> None:
    """Land; a goto meanwhile is refused (`landing`); the landing ends on the ground."""
    land = await f.accepted("land")
    await f.expect(land, "start", 10)
    here = at(f.op.last)
    reply = await f.op.send("goto", lat=here.lat, lon=here.lon)
    check(not reply.accepted and reply.reason == "landing", f"goto while landing: {reply}")
    finish = await f.expect(land, "finish", LANDING_S)
    # Telemetry goes at a lower priority than status, so a sample taken before the
    # finish can arrive after it: judge the first one taken after.
    t = await f.op.next_telemetry(lambda t: t.timestamp > finish.timestamp, 5, "telemetry after the landing")
    check(t.landed_state == "on_ground", f"landed state {t.landed_state}")


async def step_auto_disarm(f: Flight) -> None:
    """The autopilot disarms by itself after touchdown: announced once, as `system disarm`."""
    disarm = await f.op.system("disarm", 30)
    t = await f.op.next_telemetry(lambda t: t.timestamp >= disarm.timestamp, 5)
    check(not t.armed, "telemetry armed after the disarm was announced")
    await f.op.next_telemetry(lambda t: t.timestamp >= disarm.timestamp + 2000, 10, "2 s more")
    disarms = [s for s in f.op.status.items if isinstance(s, SystemStatus) and s.state == "disarm"]
    check(len(disarms) == 1, f"disarm announced {len(disarms)} times")


async def step_queued_gotos(f: Flight) -> None:
    """Arm and take off again; two gotos during the climb are queued, only the last runs."""
    await f.arm()
    takeoff = await f.accepted("takeoff", alt=TAKEOFF_ALT_M)
    here = at(f.op.last)
    east = destination(here.lat, here.lon, 15, 90)
    first = await f.accepted("goto", lat=east[0], lon=east[1])
    lat, lon = destination(here.lat, here.lon, 20, 0)
    last = await f.accepted("goto", lat=lat, lon=lon)
    await f.expect(first, "queued", 10)
    await f.expect(last, "queued", 10)
    await f.expect(first, "cancel", 10)
    await f.expect(takeoff, "finish", 60)
    await f.expect(last, "start", 10)
    await f.expect(last, "finish", 60)
    check(f.op.statuses_of(first) == ["queued", "cancel"], f"first goto: {f.op.statuses_of(first)}")
    t = await f.settle()
    check(distance_m(at(t).lat, at(t).lon, lat, lon) <= ACCEPTANCE_RADIUS_M + 1, "the last goto ended away")


async def step_return(f: Flight) -> None:
    """Return: to the home of the last arming, landed, disarmed by the autopilot."""
    ret = await f.accepted("return")
    await f.expect(ret, "start", 10)
    landed = await f.expect(ret, "finish", 180)
    t = await f.op.next_telemetry(lambda t: t.timestamp > landed.timestamp, 10, "telemetry after the return")
    home = f.armed_home
    assert home is not None
    off = distance_m(at(t).lat, at(t).lon, home.lat, home.lon)
    check(t.landed_state == "on_ground", f"landed state {t.landed_state} after the return")
    check(off < 2.0, f"the return ended {off:.1f} m from the home of the last arming")
    await f.op.next_telemetry(lambda t: not t.armed, 30, "disarmed after the return")


async def step_lost_link(f: Flight) -> None:
    """Airborne, the ground goes silent: the agent holds, then returns home and lands."""
    await f.arm()
    await f.expect(await f.accepted("takeoff", alt=TAKEOFF_ALT_M), "finish", 60)
    here = at(await f.settle())
    away = destination(here.lat, here.lon, 15, 45)
    await f.expect(await f.accepted("goto", lat=away[0], lon=away[1]), "finish", 60)
    assert f.ground is not None
    await f.ground.close()
    await f.op.system("link_lost", 15)
    hold = await f.op.system("failsafe", 10)
    check(hold.reason == "hold", f"first failsafe {hold.reason}")
    await f.op.status.wait_for(
        lambda s: isinstance(s, SystemStatus) and s.state == "failsafe" and s.reason == "return", 20, "failsafe return")
    t = await f.op.next_telemetry(lambda t: t.landed_state == "on_ground" and not t.armed, 180, "home, landed")
    home = f.armed_home
    assert home is not None
    off = distance_m(at(t).lat, at(t).lon, home.lat, home.lon)
    check(off < 2.0, f"the failsafe's return ended {off:.1f} m from home")


STEPS: list[tuple[str, Callable[[Flight], Awaitable[None]]]] = [
    ("telemetry fields and rate", step_telemetry),
    ("refusals while disarmed", step_refusals),
    ("arm", step_arm),
    ("takeoff", step_takeoff),
    ("goto, yaw null, no alt", step_goto),
    ("goto with yaw and alt", step_goto_yaw_alt),
    ("turn", step_turn),
    ("move", step_move),
    ("cancel", step_cancel),
    ("land, goto refused", step_land),
    ("auto-disarm announced", step_auto_disarm),
    ("gotos queued in a takeoff", step_queued_gotos),
    ("return to the last arming's home", step_return),
    ("lost-link failsafe", step_lost_link),
]


# ----- the autopilots ----------------------------------------------------------------

class Autopilot:
    """Something that speaks MAVLink to the agent on `fc_url`; started (as `proc`, a child
    process, if it is ours) and stopped per run."""

    name = "autopilot"
    fc_url = ""
    proc: ChildProcess | None = None

    def start(self, workdir: Path) -> None: ...

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.stop(timeout_s=15)

    def alive(self) -> bool:
        return self.proc is None or self.proc.proc.poll() is None


class FleetSim(Autopilot):
    def __init__(self, personality: str, params: list[str]) -> None:
        self.personality, self.params = personality, params
        self.name = f"fleet sim --autopilot {personality}" + "".join(f" --param {p}" for p in params)

    def start(self, workdir: Path) -> None:
        self.proc = SimProcess(workdir, extra_args=["--autopilot", self.personality,
                                                    *[f"--param={p}" for p in self.params]])
        self.fc_url = self.proc.fc_url()


class Px4Sitl(Autopilot):
    """PX4's SIH quadrotor from a build folder (build/px4_sitl_default), instance i sending
    to UDP 14540+i; parameters and mission storage wiped for a clean start."""

    def __init__(self, build: Path, instance: int, home: tuple[float, float, float] | None = None) -> None:
        """`home`: where the SIH quad stands (lat, lon, alt AMSL); PX4's default is Zürich."""
        self.build, self.instance, self.home = build, instance, home
        self.name = f"PX4 SITL (SIH quad) {build / 'bin' / 'px4'} -i {instance}"
        self.fc_url = f"udpin://127.0.0.1:{14540 + instance}"

    def start(self, workdir: Path) -> None:
        rootfs = self.build / "rootfs"
        for stale in ("parameters.bson", "parameters_backup.bson", "dataman", f"{self.instance}"):
            path = rootfs / stale
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
        env = {"PX4_SIM_MODEL": "sihsim_quadx", "PX4_SIMULATOR": "sihsim"}
        if self.home is not None:
            env |= dict(zip(("PX4_HOME_LAT", "PX4_HOME_LON", "PX4_HOME_ALT"), map(str, self.home), strict=True))
        self.proc = ChildProcess([str(self.build / "bin" / "px4"), "-i", str(self.instance), "-d"],
                                 workdir / "px4.log", env=env, cwd=rootfs)


class ArduCopterSitl(Autopilot):
    """ArduCopter's SITL binary (build/sitl/bin/arducopter), the quad model, copter.parm
    defaults of its source tree, parameters wiped, MAVLink to a UDP port of ours."""

    HOME = "40.633490,-8.660815,10,0"

    def __init__(self, binary: Path, instance: int) -> None:
        self.binary, self.instance = binary, instance
        self.name = f"ArduCopter SITL {binary} -I{instance}"

    def start(self, workdir: Path) -> None:
        port = free_udp_base(1)
        self.fc_url = f"udpin://127.0.0.1:{port}"
        parm = self.binary.resolve().parents[3] / "Tools" / "autotest" / "default_params" / "copter.parm"
        self.proc = ChildProcess(
            [str(self.binary), "--model", "quad", "--speedup", "1", "--defaults", str(parm), f"-I{self.instance}",
             "--home", self.HOME, "--wipe", "--serial0", f"udpclient:127.0.0.1:{port}"],
            workdir / "arducopter.log", cwd=workdir)


class Given(Autopilot):
    def __init__(self, url: str) -> None:
        self.fc_url, self.name = url, f"the autopilot on {url} (not restarted between runs)"


def px4_build(who: str) -> Path:
    """$FLEET_PX4_BUILD, a PX4 build folder holding bin/px4, or SystemExit naming `who` needs it."""
    build = os.environ.get("FLEET_PX4_BUILD")
    if not build or not (Path(build).expanduser() / "bin" / "px4").exists():
        raise SystemExit(f"{who} needs FLEET_PX4_BUILD, a PX4 build folder holding bin/px4 "
                         "(build/px4_sitl_default); see docs/guides/real-hardware.md")
    return Path(build).expanduser()


def autopilot_of(args: argparse.Namespace) -> Autopilot:
    if args.fc:
        return Given(args.fc)
    kind = args.autopilot
    if kind in ("sim-px4", "sim-ardupilot"):
        return FleetSim(kind.removeprefix("sim-"), args.param)
    if kind == "px4":
        return Px4Sitl(px4_build("bench/autopilot_contract.py: --autopilot px4"), args.instance)
    binary = os.environ.get("FLEET_ARDUCOPTER")
    if not binary or not Path(binary).exists():
        raise SystemExit("bench/autopilot_contract.py: --autopilot arducopter needs FLEET_ARDUCOPTER, the path of an "
                         "`arducopter` SITL binary (build/sitl/bin/arducopter); see docs/guides/real-hardware.md")
    return ArduCopterSitl(Path(binary).expanduser(), args.instance)


# ----- runs ----------------------------------------------------------------------------

@dataclass
class RunResult:
    passed: list[str]
    failed: str | None = None
    why: str = ""
    seconds: float = 0.0


async def fly_contract(fc_url: str, workdir: Path, steps: list[tuple[str, Callable[[Flight], Awaitable[None]]]] = STEPS,
                       alive: Callable[[], bool] = lambda: True) -> RunResult:
    """One run of `steps` through a fresh agent on `fc_url`, its ground a router on a free
    port and its operator on the agent's own router (which outlives the ground)."""
    result = RunResult(passed=[])
    started = time.monotonic()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    own = free_port()
    async with AsyncExitStack() as stack:
        ground = await open_ground_router(endpoint)
        stack.push_async_callback(ground.close)
        agent = AgentProcess("drone01", endpoint, workdir, fc=fc_url, listen=[f"tcp/127.0.0.1:{own}"],
                             lost_link=LOST_LINK, probe_period_ms=500, acceptance_radius=ACCEPTANCE_RADIUS_M,
                             return_altitude=10, max_speed=5)
        stack.callback(agent.stop)
        client = await ZenohBus.open("client", connect=[f"tcp/127.0.0.1:{own}"], wait=True)
        stack.push_async_callback(client.close)
        flight = Flight(Operator(client, "drone01"), ground)
        for name, step in steps:
            try:
                await step(flight)
            except (AssertionError, TimeoutError) as exc:
                result.failed, result.why = name, str(exc).splitlines()[0][:300]
                if not alive():
                    result.why += " (the autopilot exited)"
                break
            result.passed.append(name)
        result.seconds = time.monotonic() - started
        if result.failed is not None:
            (workdir / "statuses.txt").write_text("\n".join(map(repr, flight.op.status.items)))
            (workdir / "telemetry.txt").write_text("\n".join(
                f"{t.timestamp} armed={t.armed} {t.flight_mode} {t.landed_state} rel_alt={at(t).rel_alt:.2f} "
                f"speed={t.speed:.2f} down={t.velocity.down:.2f} heading={t.heading:.0f}"
                for t in flight.op.telem.items if t.position is not None))
    return result


def table(results: list[RunResult], steps: list[str]) -> str:
    n = len(results)
    width = max(map(len, steps))
    lines = [f"{'step':<{width}}  passed  failed  not reached"]
    for name in steps:
        passed = sum(name in r.passed for r in results)
        failed = sum(r.failed == name for r in results)
        lines.append(f"{name:<{width}}  {passed:>3}/{n:<3} {failed:>5}  {n - passed - failed:>10}")
    return "\n".join(lines)


async def main(args: argparse.Namespace) -> int:
    autopilot = autopilot_of(args)
    keep = Path(args.keep) if args.keep else None
    print(f"flying the agent's contract against {autopilot.name}, {args.runs} run(s)", flush=True)
    results: list[RunResult] = []
    for run in range(1, args.runs + 1):
        workdir = Path(tempfile.mkdtemp(prefix=f"contract-{run}-"))
        try:
            autopilot.start(workdir)
            result = await fly_contract(autopilot.fc_url, workdir, alive=autopilot.alive)
        finally:
            autopilot.stop()
        results.append(result)
        verdict = "passed" if result.failed is None else f"FAILED at {result.failed}: {result.why}"
        print(f"run {run}/{args.runs}: {verdict} ({result.seconds:.0f} s)", flush=True)
        if result.failed is not None and keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            shutil.copytree(workdir, keep / f"run-{run}", dirs_exist_ok=True)
            print(f"  logs kept in {keep / f'run-{run}'}", flush=True)
        shutil.rmtree(workdir, ignore_errors=True)
    print(f"\n{autopilot.name}: {sum(r.failed is None for r in results)} of {len(results)} runs passed every step")
    print(table(results, [name for name, _ in STEPS]))
    return 0 if all(r.failed is None for r in results) else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--autopilot", choices=["sim-px4", "sim-ardupilot", "px4", "arducopter"], default="sim-px4",
                       help="what to start for each run (px4: $FLEET_PX4_BUILD; arducopter: $FLEET_ARDUCOPTER)")
    where.add_argument("--fc", help="fly an autopilot already running on this MAVSDK URL instead")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="with fleet sim: an autopilot parameter (repeatable); default: the autopilot's defaults")
    parser.add_argument("--instance", type=int, default=0, help="the SITL instance number (PX4 -i, ArduCopter -I)")
    parser.add_argument("--keep", metavar="DIR", help="keep the logs of failed runs here")
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    sys.exit(asyncio.run(main(parser.parse_args())))
