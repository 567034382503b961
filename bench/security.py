"""What security costs (SPEC §9), plain TCP and the secured mesh side by side in one run.

    .venv/bin/python bench/security.py [--commands 300] [--messages 20000]

- command latency: HTTP POST /drone/drone01/cmd (`arm`) until the agent's accept, with
  `fleet ground` and one `fleet agent --fc sim` as child processes on loopback: plain
  (tcp/, unsigned) against secured (mTLS + access rules on both routers + Ed25519
  signatures checked by the agent). p50/p99 in ms.
- fan-in: a client publishing telemetry as fast as it can for `messages` samples to a
  router, a subscriber on the router's own session counting them: messages per second
  received, plain against mTLS + access rules.
- signing: Ed25519 sign (ground) and verify (agent) of one goto, in µs.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.mesh_security import mesh_security  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.auth import Signer, Verifier, load_private_key, load_public_key  # noqa: E402
from dronefleet.schemas.codec import encode  # noqa: E402
from dronefleet.schemas.commands import Goto, decode_command  # noqa: E402
from dronefleet.schemas.config_loading import Security  # noqa: E402
from tests.harness import GroundFleet, make_pki  # noqa: E402
from tests.ports import free_port
from tests.waiting import until


def quantiles(samples: list[float]) -> tuple[float, float]:
    q = statistics.quantiles(samples, n=100)
    return q[49], q[98]


async def command_latency(tmp: Path, commands: int, security: dict[str, Any] | None) -> tuple[float, float]:
    secured: dict[str, Any] = {"security": security} if security else {}
    fleet = GroundFleet(tmp, {"drone01": "sim"}, secured, scheme="tls" if security else "tcp", **secured)
    try:
        async with fleet.client() as http:
            samples = []
            for _ in range(commands):
                started = time.perf_counter()
                response = await http.post("/drone/drone01/cmd", json={"cmd": "arm"})
                samples.append((time.perf_counter() - started) * 1000)
                assert response.status_code == 200, response.text
        return quantiles(samples)
    finally:
        fleet.stop()


async def fan_in(messages: int, pki: Path | None) -> float:
    scheme = "tls" if pki else "tcp"
    endpoint = [f"{scheme}/127.0.0.1:{free_port()}"]
    security = Security(pki_dir=str(pki), tls=True) if pki else Security()
    router = await ZenohBus.open("router", listen=endpoint, extra=mesh_security(security, "ground", endpoint, router=True))
    sender = await ZenohBus.open("client", endpoint, extra=mesh_security(security, "drone01", endpoint, router=False))
    try:
        got = 0
        done = asyncio.Event()

        def count(_: Any) -> None:
            nonlocal got
            got += 1
            if got >= messages:
                done.set()

        router.subscribe("drone/drone01/telem", count, maxsize=messages + 10)
        payload = b'{"drone_id":"drone01","timestamp":1,"armed":false,"position":{"lat":40.6,"lon":-8.6,"alt":10,"rel_alt":2}}'
        sender.publish("drone/drone01/telem", payload)  # the route is known before the clock starts
        await until(lambda: got > 0, 10, "the first sample")
        got = 0
        started = time.perf_counter()
        for _ in range(messages):
            sender.publish("drone/drone01/telem", payload, reliable=True)
        try:
            await asyncio.wait_for(done.wait(), 60)
        except TimeoutError:  # reliable: none may be missing
            raise ScenarioFailed(f"fan-in over {scheme}: {got} of {messages} samples within 60 s") from None
        return messages / (time.perf_counter() - started)
    finally:
        await sender.close()
        await router.close()


def signing_us(pki: Path, rounds: int = 2000) -> tuple[float, float]:
    signer = Signer(load_private_key(pki / "signing.key"), "ground")
    verifier = Verifier(load_public_key(pki / "signing.pub"), window_s=1e9)
    commands = [Goto(drone_id="drone01", command_id=str(i), timestamp=1, lat=40.6, lon=-8.6, alt=20.0) for i in range(rounds)]
    started = time.perf_counter()
    signed = [signer.sign(command, 1) for command in commands]
    sign = (time.perf_counter() - started) / rounds * 1e6
    wires = [decode_command(encode(s)) for s in signed]
    started = time.perf_counter()
    refusals = [verifier.refusal(wire, str(i), 1) for i, wire in enumerate(wires)]
    verify = (time.perf_counter() - started) / rounds * 1e6
    if any(refusals):
        raise ScenarioFailed(f"the agent's verifier refused {sum(map(bool, refusals))} of {rounds} signed commands: "
                             f"{next(r for r in refusals if r)}")
    return sign, verify


async def run(commands: int, messages: int) -> None:
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        pki = tmp / "pki"
        make_pki(pki, {"ground": "ground", "drone01": "drone"})
        (tmp / "plain").mkdir()
        (tmp / "secure").mkdir()
        plain = await command_latency(tmp / "plain", commands, None)
        secure = await command_latency(tmp / "secure", commands, {"pki_dir": str(pki), "tls": True})
        plain_rate = await fan_in(messages, None)
        secure_rate = await fan_in(messages, pki)
        sign, verify = signing_us(pki)
    print(f"{'':<46} {'plain tcp':>14} {'mTLS+ACL+signed':>16}")
    print(f"{'command latency via HTTP, p50 (ms)':<46} {plain[0]:>14.2f} {secure[0]:>16.2f}")
    print(f"{'command latency via HTTP, p99 (ms)':<46} {plain[1]:>14.2f} {secure[1]:>16.2f}")
    print(f"{'fan-in to a router (telemetry msg/s)':<46} {plain_rate:>14,.0f} {secure_rate:>16,.0f}")
    print(f"Ed25519 per command: sign {sign:.0f} us (ground), verify {verify:.0f} us (agent)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--commands", type=int, default=300)
    parser.add_argument("--messages", type=int, default=20_000)
    args = parser.parse_args()
    asyncio.run(run(args.commands, args.messages))
