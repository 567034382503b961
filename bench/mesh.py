"""The field mesh on the emulated radio (issue 12): failover time, probe traffic,
agent cost with probes. Needs CAP_NET_ADMIN (root), like `fleet sim --radio`.

    .venv/bin/python bench/mesh.py [--trials 20] [--seconds 20] [--cpu-seconds 90]

Exits 1 over its bars: failover p50, the agent's CPU and its RSS (FAILOVER_P50_MAX_S,
CPU_MAX_PERCENT, RSS_MAX_MIB).

Topology: the ground (a router in this process, as `fleet ground`'s), drones A and B
(real `fleet agent --fc sim` processes in their own namespaces, 10 Hz telemetry,
multicast scouting on the radio), all in good range. Failover: B's direct link to the
ground is cut to 100 % loss; the time from the cut to the first telemetry sample B
sent after it arriving at the ground (it can only come through A). Then the direct
link is restored and the next trial waits until B is the ground's direct neighbour
again. Probe traffic: bytes on a third drone's radio interface with probes every
second minus the same with probes every minute (telemetry off in both).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.procstat import Window  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.datagram_echo import EchoServer  # noqa: E402
from dronefleet.bus.port import Sample, echo  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.keys import Keys  # noqa: E402
from dronefleet.sim.radio import GROUND, LOSS_STEPS, RadioModel  # noqa: E402
from dronefleet.sim.radio_net import RadioNet, RadioUnavailable, die_with_parent  # noqa: E402

GROUND_PORT = 7447
DEADLINE_S = 30.0  # for any one wait: a mesh that does not recover in this is a failure
# Issue 57's bars: within 10 % of the figures before link quality measured delivery
# (failover p50 2.0 s, the agent 1.5 % of a core and 45.2 MiB).
FAILOVER_P50_MAX_S = 2.2
CPU_MAX_PERCENT = 1.65
RSS_MAX_MIB = 49.7


class Mesh:
    def __init__(self, net: RadioNet, ground: ZenohBus, workdir: Path) -> None:
        self.net = net
        self.ground = ground
        self.workdir = workdir
        self.agents: dict[str, subprocess.Popen[bytes]] = {}
        self.last_sent: dict[str, tuple[float, int]] = {}  # drone → (received at, its timestamp ms)
        self.arrivals: list[tuple[float, str, int]] = []
        ground.subscribe("drone/*/telem", self._on_telem)

    def _on_telem(self, sample: Sample) -> None:
        drone = sample.key.split("/")[1]
        sent_ms = json.loads(sample.payload)["timestamp"]
        self.arrivals.append((time.time(), drone, sent_ms))

    def start_agent(self, drone: str, **config: int) -> subprocess.Popen[bytes]:
        cfg = self.workdir / f"{drone}.yml"
        cfg.write_text("".join(f"{k}: {v}\n" for k, v in config.items()) or "{}\n")
        fleet = str(Path(sys.executable).with_name("fleet"))
        proc = subprocess.Popen(
            [*self.net.exec_args(drone), fleet, "agent", "--id", drone, "--fc", "sim", "--config", str(cfg),
             "--connect", f"tcp/{self.net.ground_address}:{GROUND_PORT}", "--listen", "tcp/0.0.0.0:7448",
             "--mesh-interface", "radio0"],
            stdout=open(self.workdir / f"{drone}.out", "ab"), stderr=open(self.workdir / f"{drone}.log", "ab"),
            preexec_fn=die_with_parent,
        )
        self.agents[drone] = proc
        return proc

    def running(self, drone: str) -> None:
        """After a window: a dead agent's /proc entry and radio bytes still read, as nobody's."""
        if self.agents[drone].poll() is not None:
            raise ScenarioFailed(f"drone {drone}'s agent exited ({self.agents[drone].returncode}) during the window")

    def stop_agent(self, drone: str) -> None:
        proc = self.agents.pop(drone)
        proc.terminate()
        proc.wait(timeout=10)

    def cut(self, *pairs: tuple[str, str]) -> None:
        self.net.apply({tuple(sorted(p)): LOSS_STEPS for p in pairs})  # type: ignore[misc]

    def direct_neighbours(self) -> int:
        return len(list(self.ground._session.info.routers_zid()))

    async def wait(self, predicate, what: str) -> float:
        deadline = time.monotonic() + DEADLINE_S
        while not predicate():
            if time.monotonic() > deadline:
                raise ScenarioFailed(f"{what} not within {DEADLINE_S:g} s")
            await asyncio.sleep(0.005)
        return time.time()

    async def steady(self, predicate, seconds: float, what: str) -> None:
        """Until `predicate` has held for `seconds` without a break."""
        since: float | None = None

        def held() -> bool:
            nonlocal since
            if not predicate():
                since = None
                return False
            since = since or time.monotonic()
            return time.monotonic() - since >= seconds

        await self.wait(held, what)

    def sent_after(self, drone: str, t_wall: float) -> list[float]:
        return [at for at, d, sent_ms in self.arrivals if d == drone and sent_ms / 1000 > t_wall]

    def rx_tx_bytes(self, drone: str) -> int:
        total = 0
        for counter in ("rx_bytes", "tx_bytes"):
            out = subprocess.run([*self.net.exec_args(drone), "cat", f"/sys/class/net/radio0/statistics/{counter}"],
                                 capture_output=True, text=True, check=True)
            total += int(out.stdout)
        return total


async def failover(mesh: Mesh, trials: int, steady_s: float) -> list[float]:
    await mesh.wait(lambda: mesh.sent_after("B", time.time() - 0.5), "B's telemetry at the ground")
    # Warm-up: once through A, which proves the A-B link exists (not counted).
    times: list[float] = []
    for trial in range(trials + 1):
        await mesh.steady(lambda: mesh.direct_neighbours() == 2, steady_s,
                          "A and B both direct neighbours of the ground")
        now = time.time()
        await mesh.wait(lambda now=now: mesh.sent_after("B", now), "B's telemetry on the direct link")
        mesh.cut((GROUND, "B"))
        cut_at = time.time()  # the rules are in: nothing B sends from now on crosses directly
        await mesh.wait(lambda cut_at=cut_at: mesh.sent_after("B", cut_at), "B's telemetry through A")
        first = min(mesh.sent_after("B", cut_at))
        if trial:
            times.append(first - cut_at)
            print(f"  trial {trial:2d}: {first - cut_at:.2f} s (cut at {time.strftime('%H:%M:%S', time.localtime(cut_at))}"
                  f".{int(cut_at % 1 * 1000):03d})", flush=True)
        mesh.net.apply({})
    return times


async def probe_bytes(mesh: Mesh, seconds: float) -> tuple[float, float]:
    """Radio bytes/s of drone P with probes every 1 s and every 60 s, telemetry off."""
    rates = []
    for period_ms in (1000, 60_000):
        mesh.start_agent("P", telemetry_rate_ms=60_000, probe_period_ms=period_ms)
        await asyncio.sleep(5.0)  # joining, first gossip: not steady state
        b0, t0 = mesh.rx_tx_bytes("P"), time.monotonic()
        await asyncio.sleep(seconds)
        rates.append((mesh.rx_tx_bytes("P") - b0) / (time.monotonic() - t0))
        mesh.running("P")
        mesh.stop_agent("P")
    return rates[0], rates[1]


async def main(trials: int, seconds: float, cpu_seconds: float, logs: Path | None, steady_s: float) -> int:
    with RadioNet(["A", "B", "P"], RadioModel()) as net, tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmp:
        if logs is not None:
            logs.mkdir(parents=True, exist_ok=True)
            tmp = str(logs)
        listen = [f"tcp/{net.ground_address}:{GROUND_PORT}"]
        ground = await ZenohBus.open("router", listen=listen)
        datagrams = EchoServer(listen)  # as `fleet ground` serves it: the agents' delivery trains come back
        ground.serve(Keys().ground_ping(), echo)
        ground.announce(Keys().ground_alive())
        mesh = Mesh(net, ground, Path(tmp))
        try:
            mesh.start_agent("A", telemetry_rate_ms=100)
            mesh.start_agent("B", telemetry_rate_ms=100)
            print(f"failover through a neighbour, {trials} trials, each cut after B's direct link has been up "
                  f"{steady_s:g} s (radio {net.subnet})", flush=True)
            times = await failover(mesh, trials, steady_s)
            window = Window(mesh.agents["A"].pid)
            await asyncio.sleep(cpu_seconds)
            mesh.running("A")
            usage = window.stop()
            with_probes, without = await probe_bytes(mesh, seconds)
        finally:
            for drone in list(mesh.agents):
                mesh.stop_agent(drone)
            await ground.close()
            datagrams.close()
    p50_s = statistics.median(times)
    print(f"failover p50       : {p50_s:.2f} s")
    print(f"failover max       : {max(times):.2f} s")
    print(f"agent A (router, 10 Hz telemetry, probes to ground + B), {usage.window_s:.0f} s window")
    print(f"  CPU              : {usage.cpu_percent:.2f} % of one core")
    print(f"  RSS              : {usage.rss_mib:.1f} MiB")
    print(f"probe traffic      : {with_probes - without:.0f} B/s per drone (its probes to the ground and 2 neighbours, "
          f"theirs to it, its link reports; radio total {with_probes:.0f} B/s with probes every 1 s, {without:.0f} B/s every 60 s)")
    over = [what for what, bad in (
        (f"failover p50 over {FAILOVER_P50_MAX_S:g} s", p50_s > FAILOVER_P50_MAX_S),
        (f"agent CPU over {CPU_MAX_PERCENT:g} %", usage.cpu_percent > CPU_MAX_PERCENT),
        (f"agent RSS over {RSS_MAX_MIB:g} MiB", usage.rss_mib > RSS_MAX_MIB)) if bad]
    if over:
        print(f"bench/mesh.py: {', '.join(over)}", file=sys.stderr)
    return 1 if over else 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=20.0, help="each probe-traffic window (s)")
    parser.add_argument("--cpu-seconds", type=float, default=90.0,
                        help="the agent's CPU window (s): at 1.5 %% of a core a 20-s window holds 30 clock ticks, ±0.1 %% run to run")
    parser.add_argument("--steady", type=float, default=3.0,
                        help="how long B's direct link is up before each cut (s); 0: cut as soon as it is back")
    parser.add_argument("--logs", type=Path, help="keep the agents' logs here (RUST_LOG=... adds Zenoh's)")
    args = parser.parse_args()
    try:
        sys.exit(asyncio.run(main(args.trials, args.seconds, args.cpu_seconds, args.logs, args.steady)))
    except RadioUnavailable as exc:
        raise SystemExit(f"bench/mesh.py: {exc}") from None
