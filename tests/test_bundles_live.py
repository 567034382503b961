"""Task bundles with real processes (issue 14): `fleet ground`, `fleet agent --fc sim`,
the HTTP API and real Zenoh. An agent killed mid-bundle and started again reports the
bundle as failed — to the ground's log and in its record — instead of forgetting it.
"""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from tests.harness import AgentProcess, GroundFleet
from tests.helpers import until

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
