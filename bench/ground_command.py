"""Command latency through the ground: HTTP POST /drone/{id}/cmd until the agent's
accept comes back, next to the same command as a bare Zenoh get to the agent and a
bare Zenoh get/reply echo (`ground/ping`), all in the same run.

    .venv/bin/python bench/ground_command.py [--commands 1000]

`fleet ground` and one `fleet agent --fc sim` run as child processes on loopback.
The command is `arm` (accepted every time, no flight). The HTTP clients keep their
connection alive, as a dashboard or mission client would: httpx, and a plain HTTP/1.1
writer on one socket (what curl or a browser spends), which judges the ground's own cost.
Exits 1 when the plain client's p50 is over BAR times the bare get's (issue 79).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx  # noqa: E402

from dronefleet.agent.remote import send_command  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.keys import Keys  # noqa: E402
from tests.harness import AgentProcess, GroundProcess  # noqa: E402
from tests.waiting import until

BAR = 1.5  # the API's command p50 at most this many times a bare Zenoh get's


class PlainHttp:
    """One keep-alive HTTP/1.1 connection, requests written and answers read by hand."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    @classmethod
    async def open(cls, url: str) -> PlainHttp:
        host, port = url.removeprefix("http://").rstrip("/").rsplit(":", 1)
        return cls(*await asyncio.open_connection(host, int(port)))

    async def post(self, path: str, body: bytes) -> tuple[int, bytes]:
        self.writer.write(b"POST %s HTTP/1.1\r\nHost: ground\r\nContent-Type: application/json\r\n"
                          b"Content-Length: %d\r\n\r\n%s" % (path.encode(), len(body), body))
        head = await self.reader.readuntil(b"\r\n\r\n")
        status = int(head.split(b" ", 2)[1])
        length = next(int(line.split(b":", 1)[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:"))
        return status, await self.reader.readexactly(length)

    def close(self) -> None:
        self.writer.close()


async def timed(n: int, call: Callable[[], Awaitable[None]]) -> list[float]:
    for _ in range(20):  # warm the path: connections, caches
        await call()
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        await call()
        samples.append((time.perf_counter() - t0) * 1000)
    return samples


def row(name: str, samples: list[float]) -> str:
    q = statistics.quantiles(samples, n=100)
    return f"{name:<44} {len(samples):>6} {q[49]:>8.2f} {q[98]:>8.2f} {max(samples):>8.2f}"


async def main(commands: int) -> None:
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        ground = GroundProcess(tmp)
        agent = AgentProcess("drone01", ground.endpoint, tmp)
        try:
            await ground.ready()
            async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
                async def registered() -> bool:
                    return (await http.get("/drone/drone01")).status_code == 200

                await until(registered, 30, "drone01 registered")

                async def via_http() -> None:
                    response = await http.post("/drone/drone01/cmd", json={"cmd": "arm"})
                    assert response.status_code == 200, response.text

                http_ms = await timed(commands, via_http)
            plain = await PlainHttp.open(ground.url)
            try:
                async def via_plain_http() -> None:
                    status, body = await plain.post("/drone/drone01/cmd", b'{"cmd":"arm"}')
                    assert status == 200, body

                plain_ms = await timed(commands, via_plain_http)
            finally:
                plain.close()
            bus = await ZenohBus.open("client", connect=[ground.endpoint])
            try:
                async def via_zenoh() -> None:
                    reply = await send_command(bus, "drone01", "arm")
                    assert reply.accepted, reply.reason

                async def ping() -> None:
                    assert await bus.query(Keys().ground_ping(), b"ping") == b"ping"

                zenoh_ms = await timed(commands, via_zenoh)
                ping_ms = await timed(commands, ping)
            finally:
                await bus.close()
        finally:
            agent.stop()
            ground.stop()
    print(f"command -> accept latency on loopback, {commands} commands each (ms)")
    print(f"{'path':<44} {'n':>6} {'p50':>8} {'p99':>8} {'max':>8}")
    print(row("HTTP POST (httpx) -> ground -> agent accept", http_ms))
    print(row("HTTP POST (plain) -> ground -> agent accept", plain_ms))
    print(row("bare Zenoh get -> agent accept", zenoh_ms))
    print(row("bare Zenoh get/reply echo (ground/ping)", ping_ms))
    ratio = statistics.median(plain_ms) / statistics.median(zenoh_ms)
    print(f"the API's command p50 is {ratio:.2f}x a bare get's (bar {BAR}x; with httpx "
          f"{statistics.median(http_ms) / statistics.median(zenoh_ms):.2f}x)")
    if ratio > BAR:
        raise SystemExit(1)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--commands", type=int, default=1000)
    asyncio.run(main(parser.parse_args().commands))
