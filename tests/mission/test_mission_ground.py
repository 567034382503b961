"""Missions on a real ground: `fleet ground` and four `fleet agent --fc sim` over real
Zenoh, missions submitted over HTTP and with the CLI (issue 5), all on the secured mesh
(mutual TLS, access rules, signed commands: SPEC §9).

The thesis's scripts 5.3 and 5.4 fly at the same time as a third mission spins in
`while True: pass`; DELETE ends the spinning one within a second while the ground
keeps handling telemetry and the flights finish.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.harness import (
    GroundFleet,
    GroundProcess,
    ended,
    fleet_command,
    make_pki,
    record,
    seq_above,
    submit,
    telemetry_seq,
)
from tests.waiting import until

# One worker runs them all, on the module's one fleet: spread over the workers, each
# started a fleet of its own for its one or two tests. The group holds the other
# modules with a fleet of their own too, one after the other (ADR 0011).
pytestmark = [pytest.mark.integration, pytest.mark.xdist_group("module-fleets")]

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
DRONES = ("drone01", "drone02", "drone03", "drone04")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GroundFleet]:
    """On the secured mesh (SPEC §9): mTLS on every link, the routers' access rules and
    signed commands, as a fielded fleet flies."""
    # Parked 11 m apart, as real drones are: closer, a takeoff under a hovering drone is a conflict (SPEC §11).
    fcs = {d: f"sim://?lat=40.633400&lon={-8.660810 + 0.00013 * i:.6f}&alt=8.2" for i, d in enumerate(DRONES)}
    pki = make_pki(tmp_path_factory.mktemp("pki"), {"ground": "ground", **{d: "drone" for d in DRONES}})
    security = {"pki_dir": str(pki), "tls": True}
    fleet = GroundFleet(tmp_path_factory.mktemp("missions"), fcs,
                        {"telemetry_rate_ms": 200, "takeoff_altitude": 5.0, "security": security},
                        security=security, scheme="tls")
    yield fleet
    fleet.stop()


@pytest.mark.slow(45)
async def test_examples_fly_while_a_spinning_mission_is_cancelled_within_a_second(http: httpx.AsyncClient) -> None:
    sync = await submit(http, (EXAMPLES / "synchronisation.py").read_text(), "5.4")
    # Each mission runs in its own process: they claim drones in the order they get to
    # `assign`, not the order they were sent. 5.4 names drone01 and drone02; 5.3 takes any two.
    await until(lambda: _claimed(http, sync, 2), 10, "5.4 to claim its drones")
    two = await submit(http, (EXAMPLES / "two_drones.py").read_text(), "5.3")
    spin = await submit(http, "x = 0\nwhile True:\n    pass\n", "spin")
    await until(lambda: _status(http, spin, "running"), 10, "the spinning mission to run")

    # While it spins, the ground still takes telemetry in and answers HTTP.
    seq = await telemetry_seq(http, "drone01")
    await until(lambda: seq_above(http, "drone01", seq + 5), 5, "telemetry to keep flowing during the spin")

    response = await http.delete(f"/mission/{spin}")
    assert response.status_code == 200, response.text
    final = await ended(http, spin, 10)  # a liveness deadline; the spin would never end by itself
    assert (final["status"], final["cause"]) == ("cancelled", "user")
    assert (await http.delete(f"/mission/{spin}")).status_code == 409

    for mission_id in (sync, two):
        final = await ended(http, mission_id, 150)
        assert (final["status"], final["cause"]) == ("finished", "success"), final
    sync_record = await record(http, sync)
    assert sync_record["used_drones"] == ["drone01", "drone02"] and sync_record["active_drones"] == []
    assert sorted((await record(http, two))["used_drones"]) == ["drone03", "drone04"]
    messages = [line["message"] for line in sync_record["log"]]
    assert messages[0] == "Mission started" and messages[-1] == "Mission finished: success"
    listed = {r["mission_id"]: r for r in (await http.get("/mission")).json()}
    assert {sync, two, spin} <= set(listed)
    for drone_id in DRONES:
        info = (await http.get(f"/drone/{drone_id}", params={"data": "info"})).json()["info"]
        assert info["mission"] is None


async def _status(http: httpx.AsyncClient, mission_id: str, status: str) -> bool:
    return (await record(http, mission_id))["status"] == status


async def _claimed(http: httpx.AsyncClient, mission_id: str, n: int) -> bool:
    return len((await record(http, mission_id))["active_drones"]) == n


async def test_scripts_that_do_not_compile_get_400_with_line_and_column(http: httpx.AsyncClient) -> None:
    bad = await http.post("/mission", content=b"d = assign()\nif d\n    arm(d)\n")
    assert bad.status_code == 400
    assert bad.json()["detail"] == {"kind": "syntax", "line": 2, "column": 5, "message": "expected ':'"}
    escape = await http.post("/mission", content=b"x = 1\nimport os\n")
    assert escape.status_code == 400
    assert (escape.json()["detail"]["kind"], escape.json()["detail"]["line"], escape.json()["detail"]["column"]) == ("security", 2, 1)
    assert "not allowed" in escape.json()["error"]
    not_utf8 = await http.post("/mission", content=b"\xff\xfe")
    assert not_utf8.status_code == 400
    assert (await http.get("/mission/m999")).status_code == 404
    assert (await http.delete("/mission/m999")).status_code == 404


async def test_drones_of_a_mission_refuse_other_commands(http: httpx.AsyncClient) -> None:
    mission_id = await submit(http, 'd = assign("drone03")\nsleep(60)\n')
    await until(lambda: _assigned(http, "drone03", mission_id), 10, "drone03 assigned")
    refused = await http.post("/drone/drone03/cmd", json={"cmd": "arm"})
    assert refused.status_code == 409 and mission_id in refused.json()["error"]
    assert (await http.delete(f"/mission/{mission_id}")).status_code == 200
    await ended(http, mission_id, 5)
    await until(lambda: _assigned(http, "drone03", None), 5, "drone03 released")


async def _assigned(http: httpx.AsyncClient, drone_id: str, mission_id: str | None) -> bool:
    info = (await http.get(f"/drone/{drone_id}", params={"data": "info"})).json()["info"]
    return bool(info["mission"] == mission_id)


def test_cli_submit_watch_check_list_show(fleet: GroundFleet, http: httpx.AsyncClient, tmp_path: Path) -> None:
    url = ["--url", fleet.ground.url]
    good = tmp_path / "arm.py"
    good.write_text('d = assign("drone04")\narm(d)\ndisarm(d)\nprint("armed and disarmed", d.id)\n')
    done = subprocess.run(fleet_command("mission", "submit", *url, "--watch", str(good)), capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "armed and disarmed drone04" in done.stdout
    assert "finished: success" in done.stdout
    mission_id = done.stdout.split()[1]

    failing = tmp_path / "missing.py"
    failing.write_text('assign("drone09")\n')
    done = subprocess.run(fleet_command("mission", "submit", *url, "-w", str(failing)), capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "failed: requirements" in done.stdout

    listed = subprocess.run(fleet_command("mission", "list", *url), capture_output=True, text=True, timeout=30)
    assert listed.returncode == 0 and mission_id in listed.stdout and "arm.py" in listed.stdout
    shown = subprocess.run(fleet_command("mission", "show", *url, mission_id), capture_output=True, text=True, timeout=30)
    assert shown.returncode == 0 and "Assigned drone04" in shown.stdout
    cancel = subprocess.run(fleet_command("mission", "cancel", *url, mission_id), capture_output=True, text=True, timeout=30)
    assert cancel.returncode == 1 and "409" in cancel.stderr

    bad = tmp_path / "bad.py"
    bad.write_text("x = 1\nopen('f')\n")
    checked = subprocess.run(fleet_command("mission", "check", str(bad)), capture_output=True, text=True, timeout=30)
    assert checked.returncode == 1 and f"{bad}:2:1:" in checked.stderr
    checked = subprocess.run(fleet_command("mission", "check", str(EXAMPLES / "mapping.py")), capture_output=True, text=True, timeout=30)
    assert checked.returncode == 0
    rejected = subprocess.run(fleet_command("mission", "submit", *url, str(bad)), capture_output=True, text=True, timeout=30)
    assert rejected.returncode == 1 and "400" in rejected.stderr and "line 2, column 1" in rejected.stderr


@pytest.mark.parametrize("how", ["kill", "term"])
async def test_missions_survive_a_ground_restart_as_failed_ground_restart(tmp_path: Path, how: str) -> None:
    ground = GroundProcess(tmp_path)  # started by the constructor
    try:
        await ground.ready()
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as client:
            mission_id = await submit(client, "sleep(600)\n", "long")
            done_id = await submit(client, "print('quick')\n", "quick")
            await until(lambda: _status(client, mission_id, "running"), 10, "the mission to run")
            await ended(client, done_id, 10)
        if how == "kill":
            ground.kill()
        else:
            assert ground.stop() == 0
    finally:
        ground.stop()
    again = GroundProcess(tmp_path, data_dir=ground.data_dir)
    try:
        await again.ready()
        async with httpx.AsyncClient(base_url=again.url, timeout=10) as client:
            long_record = await record(client, mission_id)
            assert (long_record["status"], long_record["cause"]) == ("failed", "ground_restart")
            assert long_record["end"] is not None
            quick = await record(client, done_id)
            assert (quick["status"], quick["cause"]) == ("finished", "success")
            assert "quick" in [line["message"] for line in quick["log"]]
            assert await submit(client, "pass\n") == "m3"  # ids go on after the old ones
    finally:
        again.stop()
