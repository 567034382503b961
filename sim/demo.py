"""`fleet demo`: one simulated drone flown through its agent, live telemetry printed.

Starts a ground station in this process (Zenoh router, registry, event log in a
temporary directory, HTTP API — its URL is printed), the agent (`fleet agent --fc
sim`) as a child process, then flies arm → takeoff → a 40 m square → return to
launch, printing each telemetry sample and status as it arrives, and finally the
ground's event log. Grows into the full demo (dashboard, missions) in later issues.
"""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import tempfile
from collections.abc import Callable

import httpx

from agent.remote import send_command
from bus.port import Bus, Sample, Unreachable
from bus.zenoh_bus import ZenohBus
from ground.config import GroundConfig
from ground.lifecycle import run_ground
from schemas.codec import decode_status, decode_telemetry
from schemas.geo import destination
from schemas.keys import Keys
from schemas.status import CommandStatus, SystemStatus
from schemas.telemetry import Telemetry

DRONE = "drone01"


class _Watch:
    def __init__(self, out: Callable[[str], None]) -> None:
        self.out = out
        self.telem: Telemetry | None = None
        self.statuses: list[CommandStatus | SystemStatus] = []
        self.changed = asyncio.Event()

    def on_telem(self, sample: Sample) -> None:
        t = self.telem = decode_telemetry(sample.payload)
        if t.position and t.battery:
            self.out(
                f"  telem #{t.seq:<4} {t.flight_mode:<16} {t.landed_state:<10} armed={str(t.armed):<5} "
                f"alt={t.position.rel_alt:6.2f} m  lat={t.position.lat:.6f} lon={t.position.lon:.6f} "
                f"hdg={t.heading:5.1f}  speed={t.speed:4.1f} m/s  battery={t.battery.remaining_percent:.0%}"
            )
        self.changed.set()

    def on_status(self, sample: Sample) -> None:
        s = decode_status(sample.payload)
        self.statuses.append(s)
        what = f"{s.command} {s.state}" if isinstance(s, CommandStatus) else f"system {s.state}"
        self.out(f"* status: {what}" + (f" ({s.reason})" if s.reason else ""))
        self.changed.set()

    async def until(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        try:
            async with asyncio.timeout(timeout_s):
                while not predicate():
                    self.changed.clear()
                    await self.changed.wait()
        except TimeoutError:
            raise RuntimeError(f"no {what} within {timeout_s:g} s") from None

    def has(self, command_id: str, state: str) -> bool:
        return any(isinstance(s, CommandStatus) and s.command_id == command_id and s.state == state for s in self.statuses)


async def _fly(bus: Bus, watch: _Watch, out: Callable[[str], None]) -> bool:
    async def do(cmd: str, wait_state: str | None, timeout_s: float = 60, **fields: object) -> None:
        reply = await send_command(bus, DRONE, cmd, **fields)
        out(f"> {cmd} {fields or ''} -> {'accepted' if reply.accepted else 'refused: ' + str(reply.reason)}")
        if not reply.accepted:
            raise RuntimeError(f"{cmd} refused: {reply.reason}")
        if wait_state:
            await watch.until(lambda: watch.has(reply.command_id, wait_state) or watch.has(reply.command_id, "failure"), timeout_s, cmd)
            if watch.has(reply.command_id, "failure"):
                raise RuntimeError(f"{cmd} failed")

    await do("arm", "success", 10)
    await do("takeoff", "finish", 30, alt=10)
    assert watch.telem and watch.telem.position
    lat0, lon0 = watch.telem.position.lat, watch.telem.position.lon
    for bearing in (0, 90, 180, 270):
        lat0, lon0 = destination(lat0, lon0, 40, bearing)
        await do("goto", "finish", 30, lat=lat0, lon=lon0, yaw=None, speed=8)
    await do("return", "finish", 90, alt=15)
    await watch.until(lambda: any(isinstance(s, SystemStatus) and s.state == "disarm" for s in watch.statuses), 10, "auto disarm")
    return True


async def run_demo(port: int, http_port: int, out: Callable[[str], None]) -> bool:
    endpoint = f"tcp/127.0.0.1:{port}"
    keys = Keys()
    data_dir = tempfile.TemporaryDirectory(prefix="fleet-demo-")
    config = GroundConfig(listen=[endpoint], http_port=http_port, data_dir=data_dir.name)
    ground = asyncio.get_running_loop().create_task(run_ground(config, out), name="demo ground")
    agent = subprocess.Popen(
        [sys.executable, "-m", "fleet_cli", "agent", "--id", DRONE, "--fc", "sim", "--connect", endpoint, "--telemetry-rate-ms", "500"],
    )
    client: ZenohBus | None = None
    try:
        client = await ZenohBus.open("client", connect=[endpoint], wait=True)
        out(f"Agent {DRONE} (pid {agent.pid}) on a simulated vehicle; try `fleet drone list --url http://127.0.0.1:{http_port}`.")
        out(f"Watch the raw traffic in another terminal: fleet sub 'drone/**' --connect {endpoint}")
        watch = _Watch(out)
        client.subscribe(keys.telem(DRONE), watch.on_telem, latest_only=True)
        client.subscribe(keys.status(DRONE), watch.on_status)
        await watch.until(lambda: watch.telem is not None, 30, "first telemetry")
        try:
            ok = await _fly(client, watch, out)
        except (RuntimeError, Unreachable) as exc:
            out(f"demo failed: {exc}")
            return False
        out("Demo flight complete: the drone is home and disarmed. The ground's event log:")
        async with httpx.AsyncClient() as http:
            log = await http.get(f"http://127.0.0.1:{http_port}/drone/logs")
        for line in log.text.splitlines():
            out(f"  {line}")
        return ok
    finally:
        agent.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            agent.wait(timeout=10)
        if agent.poll() is None:
            agent.kill()
        if client is not None:
            await client.close()
        ground.cancel()
        await asyncio.gather(ground, return_exceptions=True)
        data_dir.cleanup()
