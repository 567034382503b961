"""Security (SPEC §9, issue 16): the fleet PKI, and end-to-end command authority —
the ground signs every command and bundle; an agent that knows its key refuses what is
unsigned, forged, tampered with, expired or replayed (`unauthenticated`), whatever
path it came by, while the ground's own commands and missions still fly."""

from __future__ import annotations

import json
import stat
import subprocess
from pathlib import Path
from typing import Any

import msgspec
import pytest
from click.testing import CliRunner
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from dronefleet.agent.config import AgentConfig
from dronefleet.bus.recording import read
from dronefleet.cli import main
from dronefleet.compose import SimField
from dronefleet.ground.config import GroundConfig
from dronefleet.schemas.auth import Signer, Verifier, load_private_key, load_public_key
from dronefleet.schemas.bundles import TaskBundle
from dronefleet.schemas.codec import encode
from dronefleet.schemas.commands import CommandReply, Goto, decode_command
from dronefleet.schemas.config_loading import Security
from dronefleet.sim.world import DroneSpec, Spot, World
from tests.harness import GroundFleet, make_pki
from tests.waiting import advance_until, until

EXAMPLES = Path(__file__).parents[2] / "examples"
NOW = 1_700_000_000_000


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("pki")
    runner = CliRunner()
    assert runner.invoke(main, ["pki", "init", str(directory)]).exit_code == 0
    for name, role in (("ground", "ground"), ("drone01", "drone"), ("drone02", "drone"), ("operator", "operator")):
        result = runner.invoke(main, ["pki", "issue", str(directory), name, "--role", role])
        assert result.exit_code == 0, result.output
    return directory


def test_pki_keys_are_private_certificates_name_their_node_and_nothing_is_overwritten(pki: Path) -> None:
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    for key in ("ca.key", "signing.key", "ground.key", "drone01.key"):
        assert stat.S_IMODE((pki / key).stat().st_mode) == 0o600, key
    cert = x509.load_pem_x509_certificate((pki / "drone01.pem").read_bytes())
    ca = x509.load_pem_x509_certificate((pki / "ca.pem").read_bytes())
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "drone01"
    assert cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)[0].value == "drone"
    cert.verify_directly_issued_by(ca)  # raises if the fleet CA did not sign it
    before = (pki / "drone01.key").read_bytes()
    runner = CliRunner()
    again = runner.invoke(main, ["pki", "issue", str(pki), "drone01", "--role", "drone"])
    assert again.exit_code == 1 and "drone01 already has a certificate" in again.output, again.output
    assert (pki / "drone01.key").read_bytes() == before
    twice = runner.invoke(main, ["pki", "init", str(pki)])
    assert twice.exit_code == 1 and "already holds a fleet PKI" in twice.output, twice.output
    bad = runner.invoke(main, ["pki", "issue", str(pki), "drone/*", "--role", "drone"])
    assert bad.exit_code != 0 and "not usable in a key" in bad.output, bad.output


def test_the_ground_warns_when_it_listens_or_serves_beyond_loopback_unsecured() -> None:
    from dronefleet.compose import exposure_warnings

    assert exposure_warnings(GroundConfig(listen=["tcp/127.0.0.1:7447"], data_dir=".")) == []
    assert exposure_warnings(GroundConfig(listen=["tls/0.0.0.0:7447"], data_dir=".")) == []
    (mesh,) = exposure_warnings(GroundConfig(listen=["tcp/0.0.0.0:7447", "tls/0.0.0.0:7448"], data_dir="."))
    assert "tcp/0.0.0.0:7447 without TLS" in mesh and "7448" not in mesh
    (api,) = exposure_warnings(GroundConfig(listen=["tls/0.0.0.0:7447"], http_host="0.0.0.0", data_dir="."))
    assert "HTTP API is served on 0.0.0.0 without authentication" in api


def renamed(signed: Goto, ground: str) -> Goto:
    """The signed command with its signature's signer renamed (the signature kept)."""
    assert signed.auth is not None
    return msgspec.structs.replace(signed, auth=msgspec.structs.replace(signed.auth, ground=ground))


def goto(command_id: str = "c1", lat: float = 40.6) -> Goto:
    return Goto(drone_id="drone01", command_id=command_id, timestamp=NOW, lat=lat, lon=-8.6, alt=20.0)


def test_a_verifier_takes_only_fresh_commands_the_ground_signed(pki: Path) -> None:
    signer = Signer(load_private_key(pki / "signing.key"), "ground")
    verifier = Verifier(load_public_key(pki / "signing.pub"), window_s=30)
    signed = signer.sign(goto(), NOW)
    wire = decode_command(encode(signed))  # what crosses the mesh, decoded at the agent
    assert verifier.refusal(wire, "c1", NOW + 500) is None
    assert verifier.refusal(wire, "c1", NOW + 600) == "unauthenticated: c1 was already taken (a replay)"

    rogue = Signer(Ed25519PrivateKey.generate(), "ground")
    cases = {
        "unsigned": (goto("c2"), "not signed by the ground"),
        "forged": (rogue.sign(goto("c3"), NOW), "does not verify"),
        "tampered": (msgspec.structs.replace(signer.sign(goto("c4"), NOW), lat=41.0), "does not verify"),
        "renamed signer": (renamed(signer.sign(goto("c5"), NOW), "other"), "does not verify"),
        "expired": (signer.sign(goto("c6"), NOW - 31_000), "outside the 30 s window"),
        "from the future": (signer.sign(goto("c7"), NOW + 31_000), "outside the 30 s window"),
    }
    for case, (message, reason) in cases.items():
        refusal = verifier.refusal(decode_command(encode(message)), message.command_id, NOW)
        assert refusal is not None and refusal.startswith("unauthenticated: ") and reason in refusal, (case, refusal)
    bundle = signer.sign(TaskBundle(drone_id="drone01", bundle_id="b-1", steps=[{"cmd": "arm"}]), NOW)
    assert verifier.refusal(msgspec.json.decode(encode(bundle), type=TaskBundle), "b-1", NOW) is None


def secured_field(pki: Path, tmp_path: Path) -> SimField:
    world = World(origin=Spot(lat=40.63349, lon=-8.660815, alt=8.2), drones=[
        DroneSpec(id="drone01", lat=40.63349, lon=-8.660815), DroneSpec(id="drone02", lat=40.63349, lon=-8.66069)])
    security = Security(pki_dir=str(pki))
    return SimField(world, ground_config=GroundConfig(data_dir=str(tmp_path), security=security), data_dir=tmp_path,
                    agent_config=AgentConfig(telemetry_rate_ms=200, security=security))


async def test_missions_fly_signed_and_commands_from_anyone_else_are_refused(pki: Path, tmp_path: Path) -> None:
    sim = secured_field(pki, tmp_path)
    await sim.start()
    try:
        record = await sim.run_mission((EXAMPLES / "two_drones.py").read_text(), max_s=300)
        assert (record.status, record.cause) == ("finished", "success"), record
        sent = [m for m in read(tmp_path / "missions" / f"{record.mission_id}.mcap").messages if m.kind == "Command"]
        assert len(sent) == 8 and all(json.loads(m.data)["auth"]["ground"] == "ground" for m in sent)

        await sim.clock.advance(31)  # the mission's commands are now older than the window
        # drone02's node (an authenticated mesh member) queries drone01's queryable itself.
        attacker = sim._bus("drone02")
        captured = next(m for m in sent if m.topic == "drone/drone01/cmd")
        rogue = Signer(Ed25519PrivateKey.generate(), "ground")
        fresh = Goto(drone_id="drone01", command_id="attack-1", timestamp=sim.clock.time_ms(), lat=40.6335, lon=-8.6608, alt=20.0)
        attempts = {
            "unsigned": (encode(fresh), "not signed"),
            "re-signed": (encode(rogue.sign(fresh, sim.clock.time_ms())), "does not verify"),
            "replayed late": (captured.data, "outside the 30 s window"),
        }
        statuses: list[dict[str, Any]] = []
        watch = attacker.subscribe("drone/drone01/status", lambda sample: statuses.append(json.loads(sample.payload)))
        vehicle = sim.vehicles["drone01"]
        at_rest = (vehicle.armed, round(vehicle.north, 2), round(vehicle.east, 2), round(vehicle.alt, 2))
        assert not at_rest[0]
        for case, (payload, reason) in attempts.items():
            reply = msgspec.json.decode(await attacker.query("drone/drone01/cmd", payload), type=CommandReply)
            assert not reply.accepted and reply.reason is not None and reply.reason.startswith("unauthenticated")
            assert reason in reply.reason, (case, reply.reason)

        # Within the window, a captured command is refused as a replay; the ground's own still go.
        reply = await sim.station.command("drone01", b'{"cmd": "arm"}')
        assert reply.accepted
        # One publisher's statuses arrive in order: once the ground's arm is reported, any
        # status of the refused commands would have come before it. None did, and the
        # vehicle never moved.
        await advance_until(sim, lambda: any(st.get("command_id") == reply.command_id for st in statuses), 30)
        watch.close()
        refused = {"attack-1", json.loads(captured.data)["command_id"]}
        assert not [st for st in statuses if st.get("command_id") in refused], statuses
        assert (round(vehicle.north, 2), round(vehicle.east, 2), round(vehicle.alt, 2)) == at_rest[1:]
        key = "drone/drone01/cmd"
        signed_now = sim.station._signed(decode_command(json.dumps(
            {"cmd": "disarm", "drone_id": "drone01", "command_id": "once"})))
        first = msgspec.json.decode(await attacker.query(key, encode(signed_now)), type=CommandReply)
        again = msgspec.json.decode(await attacker.query(key, encode(signed_now)), type=CommandReply)
        assert first.accepted, first
        assert not again.accepted and again.reason == "unauthenticated: once was already taken (a replay)", again
    finally:
        await sim.close()


@pytest.mark.integration
async def test_a_secured_ground_commands_its_drones_and_a_direct_query_is_refused(pki: Path, tmp_path: Path) -> None:
    """Real processes: ground and agent configured with the PKI directory; the API's
    commands fly; a Zenoh client that queries the drone's `cmd` itself is refused."""
    from dronefleet.bus.zenoh_bus import ZenohBus

    security = {"pki_dir": str(pki)}
    fleet = GroundFleet(tmp_path, {"drone01": "sim://?lat=40.6334&lon=-8.660815&alt=8.2"},
                        {"security": security, "telemetry_rate_ms": 200}, security=security)
    try:
        async with fleet.client() as http:
            response = await http.post("/drone/drone01/cmd", json={"cmd": "arm"})
            assert response.status_code == 200, response.text
            response = await http.post("/drone/drone01/cmd", json={"cmd": "takeoff", "alt": 3})
            assert response.status_code == 200, response.text
            bus = await ZenohBus.open("client", [fleet.ground.endpoint])
            try:
                raw = await bus.query("drone/drone01/cmd", b'{"cmd": "land", "drone_id": "drone01", "command_id": "x"}')
                reply = msgspec.json.decode(raw, type=CommandReply)
                assert not reply.accepted and reply.reason == "unauthenticated: not signed by the ground", reply
            finally:
                await bus.close()

            async def climbed() -> bool:
                view = (await http.get("/drone/drone01")).json()
                return view["telem"]["position"]["rel_alt"] > 2.5

            await until(climbed, 30, "drone01 climbing on the ground's signed takeoff (not landing)")
        log = fleet.agents["drone01"].output()
        assert "refused goto" not in log and "refused land x: unauthenticated: not signed by the ground" in log, log[-2000:]
    finally:
        fleet.stop()


@pytest.mark.integration
async def test_on_a_tls_mesh_only_fleet_certificates_join_and_a_drone_speaks_only_for_itself(
        pki: Path, tmp_path: Path) -> None:
    """mTLS on every link and the routers' access rules (real processes): no
    certificate or a rogue CA's cannot join; with drone02's certificate, telemetry
    published as drone01 does not reach the ground and a query on drone01's `cmd` gets
    nothing; an operator's certificate reads."""
    from dronefleet.bus.port import BusError, Unreachable
    from dronefleet.bus.zenoh_bus import ZenohBus
    from dronefleet.cli import secured_client
    from dronefleet.schemas.telemetry import Position, Telemetry

    rogue = make_pki(tmp_path / "rogue", {"drone01": "drone"})
    security = {"pki_dir": str(pki), "tls": True}
    fleet = GroundFleet(tmp_path, {"drone01": "sim://?lat=40.6334&lon=-8.660815&alt=8.2"},
                        {"security": security, "telemetry_rate_ms": 200}, security=security, scheme="tls")
    endpoint = [fleet.ground.endpoint]
    try:
        async with fleet.client() as http:  # drone01 registered: its agent joined over mTLS
            assert endpoint[0].startswith("tls/")
            assert (await http.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
            for who, extra in (("no certificate", {}), ("a rogue CA's drone01", secured_client(rogue, "drone01", endpoint))):
                with pytest.raises(BusError):
                    await ZenohBus.open("client", endpoint, extra=extra)
                    pytest.fail(f"{who} joined the mesh")

            operator = await ZenohBus.open("client", endpoint, extra=secured_client(pki, "operator", endpoint))
            intruder = await ZenohBus.open("client", endpoint, extra=secured_client(pki, "drone02", endpoint))
            try:
                seen: list[str] = []
                operator.subscribe("drone/drone01/telem", lambda s: seen.append(s.key))
                await until(lambda: seen, 10, "the operator reading drone01's telemetry")

                def telem(drone_id: str, lat: float) -> bytes:
                    return encode(Telemetry(drone_id=drone_id, timestamp=NOW, armed=False,
                                            position=Position(lat=lat, lon=10.0, alt=0.0, rel_alt=0.0)))

                for _ in range(5):
                    intruder.publish("drone/drone01/telem", telem("drone01", 10.0))
                intruder.publish("drone/drone02/telem", telem("drone02", 11.0))  # its own: this one arrives

                async def drone02_registered() -> bool:
                    return (await http.get("/drone/drone02")).status_code == 200

                await until(drone02_registered, 10, "drone02's own telemetry at the ground")
                view = (await http.get("/drone/drone01")).json()
                assert abs(view["telem"]["position"]["lat"] - 40.6334) < 0.01 and view["telem"]["armed"], view["telem"]
                with pytest.raises(Unreachable):
                    await intruder.query("drone/drone01/cmd", b'{"cmd": "disarm", "drone_id": "drone01"}', timeout_s=2)
                view = (await http.get("/drone/drone01")).json()
                assert view["telem"]["armed"] and view["info"]["current_command"] is None, view
            finally:
                await intruder.close()
                await operator.close()
        log = fleet.agents["drone01"].output()
        assert "refused disarm" not in log  # it never even reached the agent
    finally:
        fleet.stop()


@pytest.mark.integration
async def test_on_a_tls_mesh_an_observer_certificate_watches_and_never_commands(tmp_path: Path) -> None:
    """SPEC §14 on a secured mesh: a certificate issued `--role observer` (a command
    post's ground) reads every drone's traffic and may ask the grounds for what it
    missed, publishes under `ground/<its name>` only, and can neither query a drone's
    `cmd` nor speak for another ground; a ground shown that certificate but started to
    command stops at once, saying why."""
    from dronefleet.bus.port import Unreachable
    from dronefleet.bus.zenoh_bus import ZenohBus
    from dronefleet.cli import secured_client
    from tests.harness import fleet_command

    directory = make_pki(tmp_path / "pki", {"ground": "ground", "drone01": "drone", "post": "observer",
                                            "operator": "operator"})
    security = {"pki_dir": str(directory), "tls": True}
    fleet = GroundFleet(tmp_path, {"drone01": "sim://?lat=40.6334&lon=-8.660815&alt=8.2"},
                        {"security": security, "telemetry_rate_ms": 200}, security=security, scheme="tls")
    endpoint = [fleet.ground.endpoint]
    try:
        async with fleet.client() as http:
            assert (await http.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
            post = await ZenohBus.open("client", endpoint, extra=secured_client(directory, "post", endpoint))
            operator = await ZenohBus.open("client", endpoint, extra=secured_client(directory, "operator", endpoint))
            try:
                seen: list[str] = []
                post.subscribe("drone/drone01/telem", lambda s: seen.append(s.key))
                await until(lambda: seen, 10, "the observer reading drone01's telemetry")
                assert await post.query("ground/ping", b"catching up", timeout_s=5) == b"catching up"
                with pytest.raises(Unreachable):
                    await post.query("drone/drone01/cmd", b'{"cmd": "disarm", "drone_id": "drone01"}', timeout_s=2)
                heard: list[str] = []
                operator.subscribe("ground/**", lambda s: heard.append(s.key))

                async def own_heard() -> bool:  # each time: another ground's announcement, and its own
                    post.publish("ground/someone/active", b'{"ground_id": "someone", "epoch": 99, "timestamp": 0}')
                    post.publish("ground/post/log", b"{}")
                    return "ground/post/log" in heard

                await until(own_heard, 10, "the observer's own publication at an operator")
                assert "ground/post/log" in heard and "ground/someone/active" not in heard, heard
                view = (await http.get("/drone/drone01")).json()
                assert view["telem"]["armed"], view["telem"]  # never disarmed by the observer
            finally:
                await post.close()
                await operator.close()
    finally:
        fleet.stop()
    config = tmp_path / "post.yml"
    config.write_text(json.dumps({"security": {**security, "name": "post"}, "listen": ["tls/127.0.0.1:0"],
                                  "http_port": 0, "data_dir": str(tmp_path / "post-data")}))
    started = subprocess.run(fleet_command("ground", "--config", str(config)), capture_output=True, text=True,
                             timeout=60, stdin=subprocess.DEVNULL)
    assert started.returncode != 0 and "is issued --role observer" in started.stderr, started.stderr[-2000:]
    assert "Traceback" not in started.stderr
    config.write_text(json.dumps({"security": {**security, "name": "post"}, "listen": ["tls/127.0.0.1:0"], "role": "observer",
                                  "ground_id": "hq", "http_port": 0, "data_dir": str(tmp_path / "post-data")}))
    started = subprocess.run(fleet_command("ground", "--config", str(config)), capture_output=True, text=True,
                             timeout=60, stdin=subprocess.DEVNULL)
    assert started.returncode != 0 and "an observer's ground_id is its certificate's name ('post')" in started.stderr, \
        started.stderr[-2000:]


@pytest.mark.integration
async def test_routers_know_a_node_by_its_certificate_not_its_address(pki: Path, tmp_path: Path) -> None:
    """ADR 0010: a drone's router dialling a neighbour at an address the neighbour's
    certificate does not name (here 127.0.0.2; on a radio mesh, any address learnt by
    gossip) still joins, unless `security.verify_names`; a rogue CA's certificate never
    does; a client (`fleet sub`, an on-board program) always checks the name."""
    from dronefleet.bus.mesh_security import mesh_security
    from dronefleet.bus.port import BusError
    from dronefleet.bus.zenoh_bus import ZenohBus
    from dronefleet.cli import secured_client
    from tests.ports import free_port

    rogue = make_pki(tmp_path / "rogue", {"drone01": "drone"})
    endpoint = [f"tls/127.0.0.2:{free_port()}"]
    ground = await ZenohBus.open("router", listen=endpoint, extra=mesh_security(
        Security(pki_dir=str(pki), tls=True), "ground", endpoint, router=True))

    async def dial(directory: Path, **security: Any) -> None:
        extra = mesh_security(Security(pki_dir=str(directory), tls=True, **security), "drone01", endpoint, router=True)
        # Fail the open instead of retrying for ever, as an agent's router does.
        # No listener (a router's default is tcp/[::]:7447, which another test may hold).
        node = await ZenohBus.open("router", connect=endpoint, extra={**extra, "connect/exit_on_failure": True,
                                                                      "connect/timeout_ms": 2000, "listen/endpoints": []})
        await node.close()

    try:
        await dial(pki)
        with pytest.raises(BusError):
            await dial(pki, verify_names=True)
        with pytest.raises(BusError):
            await dial(rogue)
        with pytest.raises(BusError):
            await ZenohBus.open("client", endpoint, extra=secured_client(pki, "operator", endpoint))
    finally:
        await ground.close()


@pytest.mark.parametrize("name", sorted(p.name for p in (Path(__file__).parents[2] / "deploy").glob("*.yml")))
def test_every_deploy_config_loads(name: str) -> None:
    from dronefleet.schemas.config_loading import load_config

    kind = GroundConfig if name.startswith("ground") else AgentConfig
    config = load_config(kind, Path(__file__).parents[2] / "deploy" / name, {})
    if "secure" in name:
        assert config.security.tls and config.security.pki_dir
        assert all(e.startswith("tls/") for e in config.listen)


TOKENS = [{"name": "alice", "role": "operator", "token": "alice-operator-token-0001"},
          {"name": "victor", "role": "viewer", "token": "victor-viewer-token-0001"},
          {"name": "ada", "role": "admin", "token": "ada-admin-token-000000001"}]


@pytest.mark.integration
async def test_api_tokens_401_403_and_the_audit_names_the_holder(tmp_path: Path) -> None:
    """Real ground and agent: no token 401, a viewer's POST 403, an operator's command
    200; the event log and the mission record name who sent them; the OpenAPI document
    declares the scheme; the CLI reads FLEET_TOKEN."""
    import os
    import subprocess

    from tests.harness import fleet_command

    fleet = GroundFleet(tmp_path, {"drone01": "sim://?lat=40.6334&lon=-8.660815&alt=8.2"}, api={"tokens": TOKENS})
    try:
        await fleet.ground.ready()
        import httpx

        def as_(token: str | None) -> httpx.AsyncClient:
            headers = {"Authorization": f"Bearer {token}"} if token else {}
            return httpx.AsyncClient(base_url=fleet.ground.url, timeout=10, headers=headers)

        async with as_(None) as anon, as_("victor-viewer-token-0001") as viewer, as_("alice-operator-token-0001") as alice:
            refused = await anon.get("/drone")
            assert refused.status_code == 401 and refused.headers["www-authenticate"] == "Bearer"
            assert set(refused.json()) == {"error", "detail"} and "Bearer" in refused.json()["error"]
            assert (await as_("not-a-token-at-all-000").get("/drone")).status_code == 401
            assert (await anon.get("/")).status_code == 200  # the page itself is public code

            async def registered() -> bool:
                return (await viewer.get("/drone/drone01")).status_code == 200

            await until(registered, 30, "drone01 registered (read by the viewer)")
            forbidden = await viewer.post("/drone/drone01/cmd", json={"cmd": "arm"})
            assert forbidden.status_code == 403, forbidden.text
            assert forbidden.json()["detail"] == {"role": "viewer", "needed": "operator"}
            assert (await alice.post("/drone/drone01/cmd", json={"cmd": "arm"})).status_code == 200
            created = await alice.post("/mission", content=b"print('hello')\n", params={"name": "audited"})
            assert created.status_code == 201, created.text
            mission_id = created.json()["mission_id"]
            record = (await viewer.get(f"/mission/{mission_id}")).json()
            assert record["submitted_by"] == "alice"
            log = (await viewer.get("/drone/logs")).text
            assert "drone01 - arm (command " in log and "sent by alice" in log, log[-1500:]
            assert f"Mission {mission_id} submitted by alice" in log
            schema = (await viewer.get("/openapi.json")).json()
            assert schema["components"]["securitySchemes"]["bearer"] == {
                "type": "http", "scheme": "bearer", "description": schema["components"]["securitySchemes"]["bearer"]["description"]}
            assert schema["security"] == [{"bearer": []}]

        env = {**os.environ, "FLEET_TOKEN": "victor-viewer-token-0001"}
        listed = subprocess.run(fleet_command("drone", "list", "--url", fleet.ground.url), env=env, capture_output=True,
                                text=True, timeout=60)
        assert listed.returncode == 0 and "drone01" in listed.stdout, listed.stderr
        env.pop("FLEET_TOKEN")
        denied = subprocess.run(fleet_command("drone", "list", "--url", fleet.ground.url), env=env, capture_output=True,
                                text=True, timeout=60)
        assert denied.returncode == 1 and "401" in denied.stderr, denied.stderr
    finally:
        fleet.stop()


def test_bad_token_settings_are_refused_at_start(tmp_path: Path) -> None:
    from dronefleet.schemas.config_loading import load_config
    from dronefleet.schemas.errors import ConfigError

    short = tmp_path / "short.yml"
    short.write_text("api: {tokens: [{name: a, role: operator, token: short}]}\n")
    with pytest.raises(ConfigError, match="api.tokens"):
        load_config(GroundConfig, short, {})
    role = tmp_path / "role.yml"
    role.write_text("api: {tokens: [{name: a, role: pilot, token: abcdefghijklmnopq}]}\n")
    with pytest.raises(ConfigError, match="role"):
        load_config(GroundConfig, role, {})
    listed = tmp_path / "tokens.yml"
    listed.write_text("- {name: bob, role: viewer, token: bob-viewer-token-00001}\n")
    config = GroundConfig(data_dir=".", api=msgspec.convert({"tokens_file": str(listed), "tokens": TOKENS[:1]}, type=type(GroundConfig().api)))
    assert [t.name for t in config.api.all_tokens()] == ["alice", "bob"]
    listed.write_text("- {name: bob, role: boss, token: bob-viewer-token-00001}\n")
    with pytest.raises(ConfigError, match="tokens_file"):
        config.api.all_tokens()
