"""Telemetry fan-in: N drones publishing real Telemetry at 10 Hz over real Zenoh into
one ground. Finds the largest N with p99 publish→registry latency < 50 ms and no loss.

    .venv/bin/python bench/ground_fanin.py [--seconds 10] [--sizes 10,25,50,100,200,400,800]

Per size, two child processes: the ground side (a Zenoh router and the GroundStation
with its SQLite event log, exactly as `fleet ground` runs them, minus HTTP) and the
publishers (one Zenoh client session declaring N telemetry publishers, each sending
every 100 ms with staggered phases). Latency is the ground's wall clock when the
registry has taken the sample minus the sample's `timestamp` (same host, so the same
clock; 1 ms resolution because the wire timestamp is in ms). Loss is counted from
gaps in each drone's `seq`. CPU is the ground process's own (getrusage) over the
window, reported as % of one core and per 1000 msg/s.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgspec  # noqa: E402

from bench.synthetic_about import announce  # noqa: E402
from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.ground.config import GroundConfig  # noqa: E402
from dronefleet.ground.eventlog import EventLog  # noqa: E402
from dronefleet.ground.station import GroundStation  # noqa: E402
from dronefleet.schemas.codec import encode  # noqa: E402
from dronefleet.schemas.keys import Keys  # noqa: E402
from dronefleet.schemas.telemetry import Battery, GpsInfo, Home, Position, Telemetry  # noqa: E402
from tests.ports import free_port

PERIOD_S = 0.1
WARM_UP_S = 3.0
P99_LIMIT_MS = 50.0


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


async def ground_side(port: int, seconds: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        bus = await ZenohBus.open("router", listen=[f"tcp/127.0.0.1:{port}"])
        events = EventLog(Path(tmp) / "events.db")
        station = GroundStation(GroundConfig(data_dir=tmp, drone_timeout_ms=60_000), bus, events)
        latencies: list[float] = []
        seqs: dict[str, list[int]] = {}
        measuring = False
        first = asyncio.Event()
        on_telemetry = station.registry.on_telemetry

        def timed(telem: Telemetry, now_ms: int) -> Any:
            result = on_telemetry(telem, now_ms)
            first.set()
            if measuring:
                latencies.append(time.time_ns() / 1e6 - telem.timestamp)
                seqs.setdefault(telem.drone_id, []).append(telem.seq)
            return result

        station.registry.on_telemetry = timed  # type: ignore[method-assign]
        task = asyncio.get_running_loop().create_task(station.run(), name="ground station")
        print("ready", flush=True)
        try:
            async with asyncio.timeout(60):
                await first.wait()
            await asyncio.sleep(WARM_UP_S)
            measuring, t0, c0 = True, time.monotonic(), _cpu_s()
            await asyncio.sleep(seconds)
            measuring, elapsed, cpu = False, time.monotonic() - t0, _cpu_s() - c0
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await bus.close()
            events.close()
    expected = sum(max(s) - min(s) + 1 for s in seqs.values())
    received = sum(len(s) for s in seqs.values())
    return {
        "drones": len(seqs), "msg_per_s": received / elapsed, "lost": expected - received,
        "p50_ms": _percentile(latencies, 0.5), "p99_ms": _percentile(latencies, 0.99),
        "cpu_percent": 100 * cpu / elapsed,
    }


async def publishers(port: int, n: int, seconds: float) -> None:
    bus = await ZenohBus.open("client", connect=[f"tcp/127.0.0.1:{port}"], wait=True)
    keys = Keys()
    template = Telemetry(
        drone_id="", timestamp=0, armed=True, flight_mode="hold", landed_state="in_air",
        battery=Battery(remaining_percent=0.8, voltage=12.0), gps_info=GpsInfo(satellites=12, fix_type="fix_3d"),
        home=Home(lat=40.6334, lon=-8.6608, alt=8.2), position=Position(lat=40.6335, lon=-8.6607, alt=18.2, rel_alt=10.0),
    )
    drones = [(f"bench{i:04d}", keys.telem(f"bench{i:04d}")) for i in range(n)]
    announce(bus, (drone_id for drone_id, _ in drones), keys)  # what each is, first, as an agent says
    start = time.monotonic()
    next_at = [start + i * PERIOD_S / n for i in range(n)]
    seq = [0] * n
    try:
        while time.monotonic() - start < seconds:
            now = time.monotonic()
            for i, (drone_id, key) in enumerate(drones):
                if next_at[i] <= now:
                    seq[i] += 1
                    telem = msgspec.structs.replace(template, drone_id=drone_id, seq=seq[i], timestamp=time.time_ns() // 1_000_000)
                    bus.publish(key, encode(telem), reliable=False)
                    next_at[i] += PERIOD_S
            await asyncio.sleep(max(0.0, min(next_at) - time.monotonic()))
    finally:
        await bus.close()


def trial(n: int, seconds: float) -> dict[str, Any]:
    port = free_port()
    me = [sys.executable, __file__]
    ground = subprocess.Popen([*me, "ground", "--port", str(port), "--seconds", str(seconds)], stdout=subprocess.PIPE, text=True)
    assert ground.stdout is not None
    if ground.stdout.readline().strip() != "ready":
        raise ScenarioFailed(f"the ground side for {n} drones did not start (exit {ground.wait()})")
    pubs = subprocess.Popen([*me, "publish", "--port", str(port), "-n", str(n), "--seconds", str(seconds + WARM_UP_S + 5)])
    try:
        out, _ = ground.communicate(timeout=seconds + WARM_UP_S + 90)
        died = pubs.poll()  # None: still publishing, as they should be (they outlast the window)
    finally:
        pubs.terminate()
        pubs.wait(timeout=15)
    for side, code in (("publishers", died), ("ground side", ground.returncode)):  # the first is the likelier cause
        if code:  # its traceback is on stderr above
            raise ScenarioFailed(f"{n} drones: the {side} exited {code}")
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("role", nargs="?", default="run", choices=["run", "ground", "publish"])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--sizes", default="10,50,100,200,400,800,1600,2400,3200")
    parser.add_argument("--port", type=int)
    parser.add_argument("-n", type=int)
    args = parser.parse_args()
    if args.role == "ground":
        print(json.dumps(asyncio.run(ground_side(args.port, args.seconds))), flush=True)
        return
    if args.role == "publish":
        asyncio.run(publishers(args.port, args.n, args.seconds))
        return
    print(f"telemetry fan-in at 10 Hz per drone, {args.seconds:g} s windows (publishers share this machine's 2 cores)")
    print(f"{'drones':>7} {'msg/s':>8} {'lost':>6} {'p50 ms':>7} {'p99 ms':>7} {'ground CPU %':>13} {'CPU % per 1k msg/s':>19}")
    best = 0
    for n in (int(s) for s in args.sizes.split(",")):
        r = trial(n, args.seconds)
        per_k = r["cpu_percent"] / (r["msg_per_s"] / 1000) if r["msg_per_s"] else float("nan")
        ok = r["lost"] == 0 and r["p99_ms"] < P99_LIMIT_MS and r["drones"] == n
        paced = r["msg_per_s"] >= 0.97 * n / PERIOD_S  # else the publishers, not the ground, fell behind
        note = "" if ok and paced else "   <- over the limit" if not ok else "   <- publishers could not keep 10 Hz"
        print(f"{n:>7} {r['msg_per_s']:>8.0f} {r['lost']:>6} {r['p50_ms']:>7.1f} {r['p99_ms']:>7.1f} {r['cpu_percent']:>13.1f} {per_k:>19.1f}{note}")
        if not (ok and paced):
            break
        best = n
    if not best:  # the search ended at its first size: nothing was sustained to report
        raise ScenarioFailed(f"not even {args.sizes.split(',')[0]} drones sustained (p99 < {P99_LIMIT_MS:g} ms, no loss)")
    print(f"largest N sustained (p99 < {P99_LIMIT_MS:g} ms, no loss): {best}")


if __name__ == "__main__":
    main()
