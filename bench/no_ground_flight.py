"""An agent with no ground on its mesh, flown by hand over Zenoh (issue 30, SPEC §8).

    .venv/bin/python bench/no_ground_flight.py [--minutes 3] [--fc sim|mavsdk|both]

A plain Zenoh router (no `ground/alive`, no answer on `ground/ping`), `fleet agent`
with its default lost-link policy (hold after 5 s, return 30 s later) and a Zenoh
client commanding it directly, as the README invites. The client flies cycles of
arm, takeoff, queued gotos (only the last survives), turn, move, return and landing
until the minutes are up, against the agent's built-in vehicle (`--fc sim`) and
against `fleet sim` through MAVSDK (`--fc mavsdk`). The agent has never heard a
ground, so its failsafe must never act: the bench fails (exit 1, no figure) on any
`link_lost` or `failsafe` status, a command cancelled by the agent, or a command that
does not end as asked.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.zenoh_bus import ZenohBus  # noqa: E402
from dronefleet.schemas.geo import destination  # noqa: E402
from dronefleet.schemas.status import CommandStatus, SystemStatus  # noqa: E402
from tests.harness import AgentProcess, Operator, SimProcess, at, stop_all  # noqa: E402
from tests.ports import free_port


async def cycle(op: Operator, n: int) -> None:
    """One flight: arm, takeoff with gotos queued behind it, turn, move, return, landed."""
    home = at(await op.next_telemetry(lambda t: t.landed_state == "on_ground" and not t.armed, 60, "on the ground"))
    await op.expect(await op.accepted("arm"), "success", 30)
    takeoff = await op.accepted("takeoff", alt=8)
    await op.accepted("goto", lat=destination(home.lat, home.lon, 15, 0)[0], lon=home.lon)
    east = destination(home.lat, home.lon, 20 + n % 3 * 5, 90)
    goto = await op.accepted("goto", lat=east[0], lon=east[1])
    await op.expect(takeoff, "finish", 60)
    await op.expect(goto, "finish", 60)
    await op.expect(await op.accepted("turn", deg=90), "finish", 30)
    await op.expect(await op.accepted("move", y=10, speed=4), "finish", 30)
    await op.expect(await op.accepted("return"), "finish", 120)
    await op.next_telemetry(lambda t: not t.armed, 60, "disarmed after the return")


def failsafes(op: Operator) -> list[str]:
    """What the agent's lost-link failsafe did, from its statuses."""
    return [f"{s.state} {s.reason or ''}".strip() for s in op.status.items
            if isinstance(s, SystemStatus) and s.state in ("link_lost", "failsafe")] + \
        [f"{s.command} {s.command_id} cancelled: {s.reason}" for s in op.status.items
         if isinstance(s, CommandStatus) and s.state == "cancel" and "failsafe" in (s.reason or "")]


async def fly(adapter: str, minutes: float, workdir: Path) -> tuple[int, float]:
    """Cycles flown and seconds commanded, against one adapter; ScenarioFailed on any failsafe."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = await ZenohBus.open("router", listen=[endpoint])  # a plain router: no ground
    children: list[AgentProcess | SimProcess] = []
    client = None
    try:
        fc = "sim"
        if adapter == "mavsdk":
            sim = SimProcess(workdir)
            children.append(sim)
            fc = sim.fc_url()
        agent = AgentProcess("drone01", endpoint, workdir, fc=fc, telemetry_rate_ms=200)
        children.insert(0, agent)
        client = await ZenohBus.open("client", connect=[endpoint])
        op = Operator(client, "drone01")
        await op.next_telemetry(timeout_s=60, what="first telemetry")
        started, cycles = time.monotonic(), 0
        while time.monotonic() - started < minutes * 60:
            try:
                await cycle(op, cycles)
            except (AssertionError, TimeoutError) as exc:
                raise ScenarioFailed(f"{adapter}: flight {cycles + 1} did not end as asked: {exc}") from None
            cycles += 1
            print(f"  {adapter}: flight {cycles} done, {time.monotonic() - started:.0f} s commanded, "
                  f"failsafe actions so far: {len(failsafes(op))}", file=sys.stderr, flush=True)
            if failsafes(op):
                break
        if failsafes(op) or "failsafe" in agent.output():
            raise ScenarioFailed(f"{adapter}: the agent ran its lost-link failsafe with no ground on the mesh: "
                                 f"{failsafes(op) or 'see its log'}")
        return cycles, time.monotonic() - started
    finally:
        stop_all(children)
        if client is not None:
            await client.close()
        await router.close()


async def main(minutes: float, adapters: list[str]) -> None:
    with tempfile.TemporaryDirectory(prefix="fleet-noground-") as tmp:
        results = {adapter: await fly(adapter, minutes, Path(tmp)) for adapter in adapters}
    print("agent with no ground on its mesh, default lost-link policy, commanded directly over Zenoh:")
    for adapter, (cycles, seconds) in results.items():
        print(f"  --fc {adapter:6s}: {cycles} flights in {seconds:.0f} s, failsafe actions 0")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=3.0, help="commanded time per adapter")
    parser.add_argument("--fc", choices=["sim", "mavsdk", "both"], default="both")
    args = parser.parse_args()
    asyncio.run(main(args.minutes, ["sim", "mavsdk"] if args.fc == "both" else [args.fc]))
