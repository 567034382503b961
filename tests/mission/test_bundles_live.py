"""Task bundles with real processes (issue 14): `fleet ground`, `fleet agent --fc sim`,
the HTTP API and real Zenoh. An agent killed mid-bundle and started again reports the
bundle as failed — to the ground's log and in its record — instead of forgetting it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from dronefleet.bus.zenoh_bus import ZenohBus
from dronefleet.schemas.bundles import BundleStatus
from tests.harness import AgentProcess, GroundFleet, Operator
from tests.waiting import until

pytestmark = pytest.mark.integration

SPAWN = "sim://?lat=40.633490&lon=-8.660815&alt=8.2"


async def logs(http: httpx.AsyncClient) -> list[str]:
    return (await http.get("/drone/logs", params={"drone_id": "drone01"})).text.splitlines()


async def test_an_agent_restarted_mid_bundle_reports_it_failed(tmp_path: Path) -> None:
    fleet = GroundFleet(tmp_path, {"drone01": SPAWN})
    try:
        async with fleet.client() as http:
            assert (await http.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
            body = {"bundle_id": "survey-1", "timeout_s": 600,
                    "steps": [{"cmd": "takeoff", "alt": 5}, {"cmd": "move", "y": 500, "speed": 2}, {"cmd": "return"}]}
            reply = await http.post("/drone/drone01/bundle", json=body)
            assert reply.status_code == 200 and reply.json() == {"bundle_id": "survey-1", "accepted": True}, reply.text

            async def on_step_two() -> bool:
                bundle = (await http.get("/drone/drone01", params={"data": "info"})).json()["info"].get("bundle")
                return bundle is not None and bundle["step"] == 1
            await until(on_step_two, 60, "the bundle's second step")
            info = (await http.get("/drone/drone01", params={"data": "info"})).json()["info"]
            assert info["bundle"] == {"bundle_id": "survey-1", "step": 1, "steps": 3, "description": "Move 500 m forward"}
            running = (await http.get("/drone/drone01/bundle/survey-1")).json()
            assert running["state"] == "running" and running["steps_done"] == 1, running

            agent = fleet.agents["drone01"]
            agent.kill()  # SIGKILL: the record on disk says "running"
            fleet.agents["drone01"] = AgentProcess("drone01", fleet.ground.endpoint, tmp_path, fc=SPAWN)

            async def reported() -> bool:
                return any("Bundle survey-1 failed at step 2/3: the agent restarted mid-bundle" in m for m in await logs(http))
            await until(reported, 30, "the restarted agent's report")
            record = (await http.get("/drone/drone01/bundle/survey-1")).json()
            assert record["state"] == "failed" and record["reason"] == "the agent restarted mid-bundle", record
            assert [e["state"] for e in record["history"]] == ["start", "finish", "start", "failure"]
            info = (await http.get("/drone/drone01", params={"data": "info"})).json()["info"]
            assert info.get("bundle") is None

            refused = await http.post("/drone/drone01/bundle", json={"steps": [{"cmd": "goto", "lat": 40.6, "lon": 200}]})
            assert refused.status_code == 400, refused.text
            assert refused.json()["detail"] == {"field": "steps[0].lon"}
            assert refused.json()["error"].startswith("step 0: lon: Expected `float` <= 180.0")
            missing = await http.get("/drone/drone01/bundle/nope")
            assert missing.status_code == 404 and "no bundle 'nope'" in missing.json()["error"]
    finally:
        fleet.stop()


async def test_the_spec_wire_shape_over_zenoh_with_a_bundle_guard(
    agents: Callable[..., AgentProcess], operator: Callable[[str], Operator], client: ZenohBus,
) -> None:
    """SPEC §6 as another implementation's test would hold us to it: the bundle as a raw
    query on drone/<id>/bundle, progress on drone/<id>/status with only the states §6
    names (a bundle's own guard is `guard` with its reason), the record on `?id=`."""
    agents("drone01", fc=SPAWN)
    op = operator("drone01")
    await op.next_telemetry(timeout_s=30, what="first telemetry")
    await op.expect(await op.accepted("arm"), "success", 10)
    bundle = {"drone_id": "drone01", "timestamp": 1, "bundle_id": "b-wire", "on_link_loss": "continue", "timeout_s": 120,
              "until": {"field": "position.rel_alt", "op": ">", "value": 4},
              "steps": [{"cmd": "takeoff", "alt": 8}, {"wait_s": 5}, {"cmd": "return"}]}
    raw = await client.query("drone/drone01/bundle", json.dumps(bundle).encode(), timeout_s=5)
    assert json.loads(raw) == {"bundle_id": "b-wire", "accepted": True}

    def is_bundle(s: Any) -> bool:
        return isinstance(s, BundleStatus) and s.bundle_id == "b-wire"
    end = await op.status.wait_for(lambda s: is_bundle(s) and s.state != "start", 60, "the bundle's end")
    assert (end.state, end.step, end.reason, end.scope) == ("guard", 0, "position.rel_alt > 4", "bundle"), end
    # An agent that missed a probe sends its recent statuses again (the ground ignores
    # repeats; run 58, a loaded machine, saw "start" twice): one message, counted once.
    sent = dict.fromkeys((s.state, s.timestamp) for s in op.status.items if is_bundle(s))
    states = [state for state, _ in sent]
    assert states == ["start", "guard"], states  # SPEC §6's words only: no "ended"
    record = json.loads(await client.query("drone/drone01/bundle?id=b-wire", timeout_s=5))
    assert {k: record[k] for k in ("bundle_id", "state", "step", "steps_done")} == {
        "bundle_id": "b-wire", "state": "ended", "step": 0, "steps_done": 0}, record
    assert record["ended_by"] == "position.rel_alt > 4", record
