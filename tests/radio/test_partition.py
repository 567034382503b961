"""Two grounds across a partition (SPEC §14) with real processes on the emulated radio:
each side's ground and drones in network namespaces of their own (sim/radio_net.py's
RadioNet), the radio dropping every packet between the sides. On loopback no partition
holds: routers with `connect` find each other's real ports by gossip around any relay
a test cuts (ADR 0016)."""

from __future__ import annotations

import re
from pathlib import Path

import httpx
import pytest

from dronefleet.agent.remote import send_command
from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.sim.radio import GROUND, RadioModel
from dronefleet.sim.radio_net import RadioNet
from tests.harness import (
    AgentProcess,
    ChildProcess,
    GroundProcess,
    event_log,
    ground_active,
    grounds,
    stop_all,
    wait_state,
)
from tests.radio.emulated import RADIO_A
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.radio]
# The grounds log their Zenoh links opening, failing and closing: a failure shows which
# link went and whether it came back, beside what each ground decided.
LINKS_LOGGED = {"RUST_LOG": "warn,zenoh::net::runtime::orchestrator=debug,zenoh_transport::unicast=debug"}
_STORY = ("dronefleet.ground", "fleet ground:", "Closing transport", "New transport opened", "RX task failed",
          "Try to connect", "Successfully connected", "Unable to connect")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")  # Zenoh's log colours


def story(child: ChildProcess) -> str:
    """What a ground said about its links and its role, without the rest of its log."""
    lines = [_ANSI.sub("", line)[:300] for line in child.output().splitlines() if any(s in line for s in _STORY)]
    return f"--- {child.log.parent.name} ({child.name}):\n" + "\n".join(lines[-150:])


@RADIO_A
@pytest.mark.slow(10)
async def test_a_partition_gives_each_side_its_ground_and_its_heal_leaves_one_above_both(
        tmp_path: Path, radio_slot: None) -> None:
    """Bravo and drone03 on one side, alpha (priority 10) with drone01 and drone02 on the
    other, each in a network namespace of its own on one emulated radio (alpha is this
    namespace); the radio drops every packet between the sides, once bravo has heard
    alpha's epoch (a cut before that leaves bravo nothing to be newer than: it starts
    alone with epoch 1, and the drone that heard alpha's refuses it). Cut: bravo takes over
    (epoch 2) and drone03 follows it, while alpha goes on commanding its side with
    epoch 1. Healed: the grounds hear each other's epochs; the rule still chooses
    alpha, which takes epoch 3 above both and says why, and bravo stands down and says
    so; every drone has heard epoch 3, and a command stamped 1 or 2 is refused
    `stale_ground`."""
    for d in ("alpha", "bravo"):
        (tmp_path / d).mkdir()
    sides = (("alpha", "drone01", "drone02"), ("bravo", "drone03"))
    net = RadioNet(["bravo", "drone01", "drone02", "drone03"], RadioModel())
    children: list[ChildProcess] = []
    mesh: ZenohBus | None = None
    try:
        net.up()
        alpha = GroundProcess(tmp_path / "alpha", ground_id="alpha", priority=10, zenoh_host=net.ground_address,
                              env=LINKS_LOGGED)
        bravo = GroundProcess(tmp_path / "bravo", ground_id="bravo", zenoh_host=net.address("bravo"),
                              http_host=net.address("bravo"), connect=[alpha.endpoint], netns=net.netns("bravo"),
                              env=LINKS_LOGGED)
        children += [alpha, bravo]
        children += [AgentProcess(d, alpha.endpoint, tmp_path, netns=net.netns(d)) for d in ("drone01", "drone02")]
        children.append(AgentProcess("drone03", bravo.endpoint, tmp_path, netns=net.netns("drone03")))
        await alpha.ready()
        await bravo.ready()  # its API on its radio address: reached across the radio until the cut
        async with httpx.AsyncClient(base_url=alpha.url, timeout=10) as a, \
                httpx.AsyncClient(base_url=bravo.url, timeout=10) as b:
            for drone_id in ("drone01", "drone02", "drone03"):
                await wait_state(a, drone_id, "ready", 45)
            await until(lambda: ground_active(a, "alpha"), 20, "alpha active")

            async def bravo_standby_under_epoch_1() -> bool:  # it has heard alpha's epoch: the cut may come
                g = await grounds(b)
                return g.get("bravo", {}).get("active") is False and g.get("alpha", {}).get("epoch") == 1
            await until(bravo_standby_under_epoch_1, 20, "bravo standby, having heard alpha's epoch")

            cut = {(x, y): 1000 for x in (GROUND if n == "alpha" else n for n in sides[0])
                   for y in sides[1]}
            net.apply(cut)
            await until(lambda: "Ground bravo is active (epoch 2)" in bravo.output(), 20,
                        "bravo active on its side of the cut")
            drone03 = next(c for c in children if c.name == "drone03")
            await until(lambda: "ground bravo is active (epoch 2)" in drone03.output(), 10, "drone03 following bravo")
            assert await ground_active(a, "alpha")  # each side has its ground
            assert (await a.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200

            net.apply({})

            async def alpha_above_both() -> bool:
                g = await grounds(a)
                return bool(g.get("alpha", {}).get("active")) and g["alpha"]["epoch"] >= 3
            await until(alpha_above_both, 30, "alpha active again above both epochs")

            async def bravo_standby_again() -> bool:
                g = await grounds(b)
                return g.get("bravo", {}).get("active") is False and bool(g.get("alpha", {}).get("active"))
            await until(bravo_standby_again, 20, "bravo standing down after the heal")
            assert "Ground bravo is standby" in bravo.output().split("Ground bravo is active (epoch 2)")[-1]  # and says so
            lines = "\n".join(await event_log(a))  # alpha says why it took a newer epoch
            assert "Ground alpha is active (epoch 3): " in lines, lines

            mesh = await ZenohBus.open("client", connect=[alpha.endpoint], wait=True)
            for drone_id in ("drone01", "drone02", "drone03"):
                for old in (1, 2):
                    async def refuses(drone_id: str = drone_id, old: int = old) -> bool:
                        reply = await send_command(mesh, drone_id, "cancel", ground_epoch=old,
                                                   ground_id="alpha" if old == 1 else "bravo")
                        return not reply.accepted and reply.reason == "stale_ground"
                    await until(refuses, 15, f"{drone_id} refusing epoch {old}")
    except AssertionError as exc:
        raise AssertionError("\n".join([str(exc), *(story(c) for c in children if isinstance(c, GroundProcess))])) from exc
    finally:
        if mesh is not None:
            await mesh.close()
        try:
            stop_all(reversed(children))
        finally:
            net.close()
