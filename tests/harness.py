"""Integration-test harness: a real Zenoh router in-process, agents as subprocesses,
and an Operator that commands them over real Zenoh and watches what they publish."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import httpx
import yaml

from dronefleet.agent.remote import send_command
from dronefleet.bus.port import Sample, echo
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.codec import decode_status, decode_telemetry
from dronefleet.schemas.commands import CommandReply
from dronefleet.schemas.keys import Keys
from dronefleet.schemas.status import CommandStatus, SystemStatus
from dronefleet.schemas.telemetry import Position, Telemetry
from tests.ports import free_port, free_udp_base
from tests.waiting import Collector, until

REPO = Path(__file__).resolve().parents[1]


def signal_and_wait(proc: subprocess.Popen[Any], sig: int, timeout_s: float, name: str = "process") -> int:
    """Send `sig` and wait for the exit; past `timeout_s` kill it (a test never leaves
    one behind) and fail."""
    proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"{name} did not stop within {timeout_s:g} s on {signal.Signals(sig).name}") from None


def in_netns(netns: str | None, command: list[str]) -> list[str]:
    """`command` run in network namespace `netns` (`ip netns exec` execs it: the child's
    pid is the command's), or as it is."""
    return command if netns is None else ["ip", "netns", "exec", netns, *command]


def fleet_command(*args: str) -> list[str]:
    """`fleet …` through the installed console script next to this interpreter."""
    script = Path(sys.executable).with_name("fleet")
    return [str(script), *args] if script.exists() else [sys.executable, "-m", "dronefleet", *args]


async def open_ground_router(endpoint: str) -> ZenohBus:
    """A bare router playing the ground as `fleet ground` does: it announces
    `ground/alive` (agents wait for it at start) and answers their link probes on
    `ground/ping`, so they do not fall into lost-link."""
    bus = await ZenohBus.open("router", listen=[endpoint])
    bus.serve(Keys().ground_ping(), echo)
    bus.announce(Keys().ground_alive())
    return bus


def make_pki(directory: Path, nodes: dict[str, str]) -> Path:
    """A fleet PKI (SPEC §9) in `directory` with a certificate per node name → role."""
    from dronefleet.pki import init, issue

    init(directory)
    for name, role in nodes.items():
        issue(directory, name, role)
    return directory


class ChildProcess:
    """A `fleet …` child process logging to a file; always stopped by whoever made it."""

    name = "process"

    def __init__(self, args: list[str], log: Path, env: Mapping[str, str] | None = None, cwd: Path = REPO) -> None:
        """`env`: variables set for the child on top of this process's environment."""
        self.args = args
        self.log = log
        self.env = None if env is None else {**os.environ, **env}
        self.cwd = cwd
        self.proc = self._spawn()

    def _spawn(self) -> subprocess.Popen[bytes]:
        with open(self.log, "ab") as out:  # the child holds its own copy of the descriptor
            return subprocess.Popen(self.args, stdout=out, stderr=subprocess.STDOUT, cwd=self.cwd, env=self.env)

    def start(self) -> None:
        """Start it again (after a stop or a kill)."""
        self.proc = self._spawn()

    def kill(self) -> None:
        """SIGKILL: no cleanup of any kind, as in a crash."""
        self.proc.kill()
        self.proc.wait()

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10) -> int | None:
        if self.proc.poll() is not None:
            return self.proc.returncode
        try:
            return signal_and_wait(self.proc, sig, timeout_s, self.name)
        except AssertionError as exc:
            raise AssertionError(f"{exc}:\n{self.output()[-3000:]}") from None

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""


def stop_all(children: Iterable[ChildProcess]) -> None:
    """Stop every child in order, also when one fails to stop (it is killed); then fail
    with the first failure, so no process is left to load the tests that follow."""
    failures: list[AssertionError] = []
    for child in children:
        try:
            child.stop()
        except AssertionError as exc:
            failures.append(exc)
    if failures:
        raise failures[0]


class AgentProcess(ChildProcess):
    """`fleet agent` as a child process."""

    def __init__(self, drone_id: str, endpoint: str, tmp: Path, fc: str = "sim", extra_args: Sequence[str] = (),
                 netns: str | None = None, **config: Any) -> None:
        """`netns`: run it in that network namespace (`ip netns exec`)."""
        config.setdefault("listen", [f"{endpoint.split('/')[0]}/127.0.0.1:0"])  # tls/… on a secured mesh
        self.drone_id = self.name = drone_id
        cfg = tmp / f"{drone_id}.yml"
        # Each agent's own router on an ephemeral loopback port: several share this host.
        cfg.write_text(yaml.safe_dump({"telemetry_rate_ms": 100, "listen": ["tcp/127.0.0.1:0"], **config}))
        super().__init__(
            in_netns(netns, fleet_command("-v", "agent", "--id", drone_id, "--config", str(cfg), "--fc", fc,
                                          "--connect", endpoint, *extra_args)),
            tmp / f"{drone_id}.log",
        )


def at(telemetry: Telemetry) -> Position:
    """The sample's position, which a test's flight always has (an assertion otherwise)."""
    assert telemetry.position is not None, telemetry
    return telemetry.position


class Operator:
    """Sends commands to one drone and records its telemetry and statuses."""

    def __init__(self, bus: ZenohBus, drone_id: str) -> None:
        self.bus = bus
        self.drone_id = drone_id
        self.telem = Collector()
        self.status = Collector()
        self.raw_telem: list[bytes] = []
        keys = Keys()

        def on_telem(sample: Sample) -> None:
            self.raw_telem.append(sample.payload)
            self.telem(decode_telemetry(sample.payload))

        bus.subscribe(keys.telem(drone_id), on_telem, maxsize=100_000)
        bus.subscribe(keys.status(drone_id), lambda s: self.status(decode_status(s.payload)), maxsize=100_000)

    @property
    def last(self) -> Telemetry:
        assert self.telem.items, "no telemetry yet"
        return self.telem.items[-1]

    async def send(self, cmd: str, **fields: Any) -> CommandReply:
        return await send_command(self.bus, self.drone_id, cmd, **fields)

    async def accepted(self, cmd: str, **fields: Any) -> str:
        reply = await self.send(cmd, **fields)
        assert reply.accepted, f"{cmd} {fields} refused: {reply.reason}"
        return reply.command_id

    async def command_state(self, command_id: str, state: str, timeout_s: float = 30) -> CommandStatus:
        return await self.status.wait_for(
            lambda s: isinstance(s, CommandStatus) and s.command_id == command_id and s.state in (state, "failure"),
            timeout_s, f"{state} of {command_id}",
        )

    async def expect(self, command_id: str, state: str, timeout_s: float = 30) -> CommandStatus:
        status = await self.command_state(command_id, state, timeout_s)
        assert status.state == state, f"expected {state}, got {status}"
        return status

    async def system(self, state: str, timeout_s: float = 10) -> SystemStatus:
        return await self.status.wait_for(
            lambda s: isinstance(s, SystemStatus) and s.state == state, timeout_s, f"system {state}"
        )

    async def next_telemetry(self, predicate: Any = lambda t: True, timeout_s: float = 30, what: str = "telemetry") -> Telemetry:
        return await self.telem.wait_for(predicate, timeout_s, what, start=len(self.telem.items))

    def statuses_of(self, command_id: str) -> list[str]:
        return [s.state for s in self.status.items if isinstance(s, CommandStatus) and s.command_id == command_id]




os.environ.setdefault("PYTHONUNBUFFERED", "1")


class SimProcess(ChildProcess):
    """`fleet sim` as a child process on a unique port range."""

    name = "fleet sim"

    def __init__(self, tmp: Path, n: int = 1, base_port: int | None = None, extra_args: Sequence[str] = ()) -> None:
        self.base_port = base_port or free_udp_base(n)
        self.n = n
        super().__init__(
            fleet_command("sim", "-n", str(n), "--base-port", str(self.base_port), *extra_args),
            tmp / f"sim-{self.base_port}.log",
        )

    def fc_url(self, i: int = 0) -> str:
        return f"udpin://127.0.0.1:{self.base_port + i}"

    @property
    def control(self) -> tuple[str, int]:
        return ("127.0.0.1", self.base_port - 1)


class GroundProcess(ChildProcess):
    """`fleet ground` as a child process on unique ports, with its own data dir."""

    name = "fleet ground"

    def __init__(
        self, tmp: Path, data_dir: Path | None = None, extra_args: Sequence[str] = (), *,
        zenoh_host: str = "127.0.0.1", scheme: str = "tcp", netns: str | None = None,
        env: Mapping[str, str] | None = None, **config: Any,
    ) -> None:
        """`netns`: run it in that network namespace (its HTTP API is then on that
        namespace's loopback, unless config `http_host` puts it on an address this
        namespace reaches)."""
        self.zenoh_port = free_port()
        self.http_port = free_port()
        self.endpoint = f"{scheme}/{zenoh_host}:{self.zenoh_port}"
        self.url = f"http://{config.get('http_host', '127.0.0.1')}:{self.http_port}"
        self.data_dir = data_dir or tmp / "ground-data"
        cfg = tmp / f"ground-{self.http_port}.yml"
        # Missions here are tested for how they fly; each submission's preflight (fast time
        # against the live fleet first, on by default) is tested in tests/mission/test_preflight.py.
        config = {**config, "mission": {"preflight": False, **config.get("mission", {})}}
        cfg.write_text(yaml.safe_dump(config))
        super().__init__(
            in_netns(netns, fleet_command(
                "-v", "ground", "--config", str(cfg), "--listen", self.endpoint,
                "--http-port", str(self.http_port), "--data-dir", str(self.data_dir), *extra_args,
            )),
            tmp / f"ground-{self.http_port}.log",
            env,
        )

    async def ready(self, timeout_s: float = 45) -> None:
        """Wait until the HTTP API answers (the router is up before it). About 1 s on an
        idle machine; over 15 s was seen at the start of `make test`, when the longest
        tests and the lint all start at once on two cores."""
        async with httpx.AsyncClient(base_url=self.url) as http:
            async def answers() -> bool:
                assert self.proc is not None and self.proc.poll() is None, f"ground exited:\n{self.output()}"
                try:
                    return (await http.get("/")).status_code == 200
                except httpx.TransportError:
                    return False

            await until(answers, timeout_s, "the ground's HTTP API")


class GroundFleet:
    """A `fleet ground` and `fleet agent --fc sim` children, one per (drone id, fc url)."""

    def __init__(self, tmp: Path, fcs: dict[str, str], agent_config: dict[str, Any] | None = None,
                 per_agent: dict[str, dict[str, Any]] | None = None, **ground_config: Any) -> None:
        """`agent_config` for every agent, `per_agent` (drone id → keys) on top of it."""
        self.tmp = tmp
        self.ground = GroundProcess(tmp, **ground_config)
        self.agents = {
            d: AgentProcess(d, self.ground.endpoint, tmp, fc=fc, **{**(agent_config or {}), **(per_agent or {}).get(d, {})})
            for d, fc in fcs.items()
        }

    def stop(self) -> None:
        stop_all([*self.agents.values(), self.ground])

    @contextlib.asynccontextmanager
    async def client(self, drones_ready: bool = True) -> AsyncIterator[httpx.AsyncClient]:
        """An HTTP client to the ground once it answers (and, if asked, every drone is `ready`)."""
        await self.ground.ready()
        async with httpx.AsyncClient(base_url=self.ground.url, timeout=10) as http:
            for drone_id in self.agents if drones_ready else ():
                await wait_state(http, drone_id, "ready", 30)
            yield http


async def drone_state(http: httpx.AsyncClient, drone_id: str) -> str | None:
    response = await http.get(f"/drone/{drone_id}", params={"data": "info"})
    return response.json()["info"]["state"] if response.status_code == 200 else None


async def wait_state(http: httpx.AsyncClient, drone_id: str, state: str, timeout_s: float) -> None:
    async def reached() -> bool:
        return await drone_state(http, drone_id) == state

    await until(reached, timeout_s, f"{drone_id} {state}")


async def ready_at(ground: GroundProcess, drone_id: str, timeout_s: float = 30) -> None:
    """Once `ground` answers, wait until it shows `drone_id` ready."""
    await ground.ready()
    async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
        await wait_state(http, drone_id, "ready", timeout_s)


# ---- missions over HTTP ----------------------------------------------------


async def submit(http: httpx.AsyncClient, source: str, name: str = "") -> str:
    response = await http.post("/mission", content=source.encode(), params={"name": name})
    assert response.status_code == 201, response.text
    return str(response.json()["mission_id"])


async def record(http: httpx.AsyncClient, mission_id: str) -> dict[str, Any]:
    response = await http.get(f"/mission/{mission_id}")
    assert response.status_code == 200, response.text
    return dict(response.json())


async def grounds(http: httpx.AsyncClient) -> dict[str, dict[str, Any]]:
    """The grounds a ground has heard (`GET /ground`, SPEC §14), by ground id."""
    return {g["ground_id"]: g for g in (await http.get("/ground")).json()}


async def ground_active(http: httpx.AsyncClient, ground_id: str) -> bool:
    """Whether the ground behind `http` holds `ground_id` for the active one."""
    return bool((await grounds(http)).get(ground_id, {}).get("active"))


async def event_log(http: httpx.AsyncClient) -> list[str]:
    """The ground's event log (`GET /drone/logs`), a line each."""
    return (await http.get("/drone/logs")).text.splitlines()


async def ended(http: httpx.AsyncClient, mission_id: str, timeout_s: float) -> dict[str, Any]:
    async def done() -> dict[str, Any] | None:
        r = await record(http, mission_id)
        return r if r["end"] is not None else None

    return dict(await until(done, timeout_s, f"mission {mission_id} to end"))


async def telemetry_seq(http: httpx.AsyncClient, drone_id: str) -> int:
    response = await http.get(f"/drone/{drone_id}", params={"data": "telem"})
    return int(response.json()["telem"]["seq"])


async def seq_above(http: httpx.AsyncClient, drone_id: str, seq: int) -> bool:
    return await telemetry_seq(http, drone_id) > seq


def two_grounds_and_fleet(tmp: Path, spawns: dict[str, tuple[float, float]],
                          **agent_config: Any) -> tuple[GroundProcess, GroundProcess, list[AgentProcess]]:
    """Two grounds as in `two_grounds` and a sim agent per spawn, connected to both."""
    for d in ("alpha", "bravo"):
        (tmp / d).mkdir()
    alpha = GroundProcess(tmp / "alpha", ground_id="alpha", priority=10)
    bravo = GroundProcess(tmp / "bravo", ground_id="bravo", connect=[alpha.endpoint])
    agents = [AgentProcess(d, alpha.endpoint, tmp, fc=f"sim://?lat={lat}&lon={lon}&alt=8.2",
                           extra_args=["--connect", bravo.endpoint], **agent_config)
              for d, (lat, lon) in spawns.items()]
    return alpha, bravo, agents


def two_grounds(tmp: Path) -> tuple[GroundProcess, GroundProcess, AgentProcess]:
    """SPEC §14's smallest mesh, not started: alpha (priority 10: active), bravo joining
    alpha's router (standby), and drone01's agent connected to both."""
    for d in ("alpha", "bravo"):
        (tmp / d).mkdir()
    alpha = GroundProcess(tmp / "alpha", ground_id="alpha", priority=10)
    bravo = GroundProcess(tmp / "bravo", ground_id="bravo", connect=[alpha.endpoint])
    return alpha, bravo, AgentProcess("drone01", alpha.endpoint, tmp, extra_args=["--connect", bravo.endpoint])
