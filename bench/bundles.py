"""Task bundles (issue 14): push → first step started, validation, status traffic.

    .venv/bin/python bench/bundles.py [--pushes 200]

- push → first step: `fleet ground` and one `fleet agent --fc sim` as child processes
  on loopback; each push is POST /drone/drone01/bundle with one `arm` step (accepted
  every time, no flight), timed until the bundle's `start` status reaches a Zenoh
  subscriber on the drone's status key. p50/p99/max in ms.
- validation: `parse_bundle` of a 1000-step bundle (goto steps, each with a guard).
- status traffic per step: bytes published on drone/<id>/status for the push above,
  divided by its steps.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx  # noqa: E402

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.bundles import parse_bundle  # noqa: E402
from dronefleet.schemas.keys import Keys  # noqa: E402
from tests.harness import AgentProcess, GroundProcess  # noqa: E402
from tests.waiting import until


def validation_ms(steps: int = 1000, rounds: int = 20) -> float:
    body = json.dumps({"drone_id": "drone01", "timestamp": 1, "bundle_id": "b", "steps": [
        {"cmd": "goto", "lat": 40.6 + i * 1e-5, "lon": -8.6, "alt": 20,
         "until": {"any": [{"field": "sensor.temperature", "op": ">", "value": 37},
                           {"field": "battery.remaining_percent", "op": "<", "value": 0.3}]}}
        for i in range(steps)]}).encode()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        parse_bundle(body)
        times.append((time.perf_counter() - t0) * 1000)
    return statistics.median(times)


async def push_latency(pushes: int) -> tuple[list[float], float]:
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        ground = GroundProcess(tmp)
        agent = AgentProcess("drone01", ground.endpoint, tmp, state_dir=str(tmp / "state"))
        starts: dict[str, asyncio.Future[float]] = {}
        status_bytes = 0
        bus: ZenohBus | None = None

        def on_status(sample: object) -> None:
            nonlocal status_bytes
            payload = sample.payload  # type: ignore[attr-defined]
            status_bytes += len(payload)
            message = json.loads(payload)
            fut = starts.get(message.get("bundle_id", ""))
            if fut is not None and message["state"] == "start" and not fut.done():
                fut.set_result(time.perf_counter())

        try:
            await ground.ready()
            bus = await ZenohBus.open("client", connect=[ground.endpoint])
            bus.subscribe(Keys().status("drone01"), on_status, maxsize=100_000)
            async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
                async def ready() -> bool:
                    r = await http.get("/drone/drone01", params={"data": "info"})
                    return r.status_code == 200 and r.json()["info"]["state"] == "ready"
                await until(ready, 30, "drone01 ready")
                samples = []
                status_bytes = 0
                for i in range(pushes + 10):
                    bundle_id = f"bench-{i}"
                    starts[bundle_id] = asyncio.get_running_loop().create_future()
                    t0 = time.perf_counter()
                    r = await http.post("/drone/drone01/bundle", json={"bundle_id": bundle_id, "steps": [{"cmd": "arm"}]})
                    if r.status_code != 200:
                        raise ScenarioFailed(f"push {i} answered {r.status_code}: {r.text}")
                    try:
                        t1 = await asyncio.wait_for(starts[bundle_id], 10)
                    except TimeoutError:
                        raise ScenarioFailed(f"push {i} accepted, but its start status not heard within 10 s") from None
                    if i >= 10:  # warm-up
                        samples.append((t1 - t0) * 1000)
                per_step = status_bytes / (pushes + 10)
        finally:
            if bus is not None:  # also on a failure: an open session keeps the interpreter from exiting
                await bus.close()
            agent.stop()
            ground.stop()
    return samples, per_step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pushes", type=int, default=200)
    args = parser.parse_args()
    print(f"validation of a 1000-step bundle: {validation_ms():.1f} ms (median of 20)")
    samples, per_step = asyncio.run(push_latency(args.pushes))
    q = statistics.quantiles(samples, n=100)
    print(f"push -> first step started ({len(samples)} pushes, loopback): p50 {q[49]:.2f} ms, p99 {q[98]:.2f} ms, max {max(samples):.2f} ms")
    print(f"status traffic: {per_step:.0f} bytes per one-step bundle (bundle start/finish/done + the arm's statuses)")


if __name__ == "__main__":
    main()
