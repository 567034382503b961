"""The CLI boundary (issue 13): every user error ends in one line naming what is wrong
and exit 1 (a runtime failure) or 2 (bad usage or configuration), never a traceback.
Each command runs as a user would run it, in a subprocess."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml

from tests.harness import fleet_command, make_pki

pytestmark = pytest.mark.integration

EXAMPLE = "examples/two_drones.py"
DEAD_URL = "http://127.0.0.1:9"  # discard port: nothing listens there


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("bad")
    (d / "bad_world.yml").write_text("drones: [{id: d1, bogus: 1}]\n")
    (d / "gas_world.yml").write_text("drones: [{id: d1, sensors: [gas, sonar]}]\nfields: {gas: {co_ppm: {background: 2}}}\n"
                                     "field_sensors: [{id: gas07, type: gas, lat: 40.6, lon: -8.6}]\n")
    (d / "bad_agent.yml").write_text("telemetry_rate_ms: 100\nwings: 4\n")
    (d / "bad_ground.yml").write_text("http_port: many\n")
    (d / "not_yaml.yml").write_text("drones: [unclosed\n")
    (d / "syntax.py").write_text("takeoff(\n")
    (d / "a_file").write_text("")
    (d / "empty_pki").mkdir()
    (d / "junk.mcap").write_bytes(b"junk junk junk")
    twice = {"name": "a", "role": "admin", "token": "x" * 20}
    (d / "dup_tokens.yml").write_text(yaml.safe_dump({"http_port": 0, "api": {"tokens": [twice, {**twice, "name": "b"}]}}))
    make_pki(d / "pki_ok", {"ground": "ground", "d1": "drone"})
    for broken, damage in (("pki_no_signing_key", "signing.key"), ("pki_no_signing_pub", "signing.pub"),
                           ("pki_corrupt_pem", "ground.pem")):
        pki = make_pki(d / broken, {"ground": "ground", "d1": "drone"})
        if damage.endswith(".pem"):
            (pki / damage).write_text("-----BEGIN CERTIFICATE-----\ngarbage\n-----END CERTIFICATE-----\n")
        else:
            (pki / damage).unlink()
    (d / "world_lat.yml").write_text("drones: [{id: d1, lat: 95}]\n")
    (d / "world_fault.yml").write_text("drones: [{id: d1, faults: [{at_s: 5, fault: meteor}]}]\n")
    (d / "world_empty.yml").write_text("drones: []\n")
    (d / "world_autopilot.yml").write_text("drones: [{id: d1, autopilot: inav}]\n")
    return d


def tls_ground(pki: str) -> list[str]:
    """`fleet ground` with --pki-dir {d}/<pki> on a TLS endpoint."""
    return ["ground", "--pki-dir", f"{{d}}/{pki}", "--listen", "tls/127.0.0.1:0", "--http-port", "0"]


def tls_agent(pki: str) -> list[str]:
    """`fleet agent` with --pki-dir {d}/<pki> and TLS endpoints."""
    return ["agent", "--id", "d1", "--fc", "sim", "--pki-dir", f"{{d}}/{pki}",
            "--connect", "tls/127.0.0.1:1", "--listen", "tls/127.0.0.1:0"]


# (name, argv with {d} for the temporary folder, allowed exit codes, a word the message must name)
CASES = [
    ("simulate: bad world", ["mission", "simulate", EXAMPLE, "--world", "{d}/bad_world.yml"], {2}, "bogus"),
    ("simulate: world latitude out of range", ["mission", "simulate", EXAMPLE, "--world", "{d}/world_lat.yml"], {2},
     "drones[0].lat"),
    ("simulate: unknown fault name", ["mission", "simulate", EXAMPLE, "--world", "{d}/world_fault.yml"], {2}, "meteor"),
    ("simulate: a world listing no drones", ["mission", "simulate", EXAMPLE, "--world", "{d}/world_empty.yml"], {2},
     "drones"),
    ("simulate: world not YAML", ["mission", "simulate", EXAMPLE, "--world", "{d}/not_yaml.yml"], {2}, "not_yaml.yml"),
    ("simulate: --out not writable", ["mission", "simulate", EXAMPLE, "--out", "{d}/a_file/out"], {1, 2}, "a_file"),
    ("simulate: unknown plugin", ["mission", "simulate", EXAMPLE, "--enable", "nothing"], {2}, "nothing"),
    ("check: syntax error", ["mission", "check", "{d}/syntax.py"], {1}, "syntax.py:"),
    ("check: no such file", ["mission", "check", "{d}/missing.py"], {2}, "missing.py"),
    ("fault: bad --control port", ["fault", "d1", "rc_takeover", "--control", "127.0.0.1:abc"], {2}, "--control"),
    ("sub: bad endpoint", ["sub", "--connect", "notanendpoint", "--count", "1"], {2}, "notanendpoint"),
    ("agent: bad endpoint", ["agent", "--id", "d1", "--fc", "sim", "--connect", "tcp/127.0.0.1:notaport"], {2}, "notaport"),
    ("agent: bad listen", ["agent", "--id", "d1", "--fc", "sim", "--listen", "nowhere"], {2}, "nowhere"),
    ("agent: bad id", ["agent", "--id", "bad id!", "--fc", "sim"], {2}, "bad id!"),
    ("agent: unknown config key", ["agent", "--id", "d1", "--config", "{d}/bad_agent.yml"], {2}, "wings"),
    ("agent: missing config", ["agent", "--id", "d1", "--config", "{d}/missing.yml"], {2}, "missing.yml"),
    ("agent: bad fc url", ["agent", "--id", "d1", "--fc", "carrier-pigeon://x"], {1, 2}, "carrier-pigeon"),
    ("agent: unknown sim:// parameter", ["agent", "--id", "d1", "--fc", "sim://?lat=40.6&speed=3"], {2}, "speed"),
    ("agent: sim:// value not a number", ["agent", "--id", "d1", "--fc", "sim://?alt=high"], {2}, "high"),
    ("agent: --pki-dir without certificates (TLS on)", tls_agent("empty_pki"), {2}, "ca.pem"),
    ("ground: --pki-dir without certificates", tls_ground("empty_pki"), {2}, "ca.pem"),
    ("ground: PKI without signing.key", tls_ground("pki_no_signing_key"), {2}, "signing.key"),
    ("ground: corrupt certificate", tls_ground("pki_corrupt_pem"), {2}, "ground.pem is not a PEM certificate"),
    ("agent: PKI without signing.pub", tls_agent("pki_no_signing_pub"), {2}, "signing.pub"),
    ("ground: the same API token twice", ["ground", "--config", "{d}/dup_tokens.yml", "--listen", "tcp/127.0.0.1:0",
                                          "--data-dir", "{d}/ground_data"], {2}, "the same token is given twice"),
    ("ground: TLS on with a tcp/ endpoint", ["ground", "--pki-dir", "{d}/pki_ok", "--listen", "tcp/127.0.0.1:0",
                                             "--http-port", "0"], {2}, "every endpoint must be tls/"),
    ("ground: bad config value", ["ground", "--config", "{d}/bad_ground.yml"], {2}, "http_port"),
    ("ground: bad listen", ["ground", "--listen", "tcp/127.0.0.1:99999"], {2}, "99999"),
    ("ground: address not here", ["ground", "--listen", "tcp/192.0.2.1:7447", "--http-port", "0"], {1}, "192.0.2.1"),
    ("drone wait: no ground, the timeout names who is missing",
     ["drone", "wait", "drone01", "drone02", "--timeout", "1", "--url", "http://127.0.0.1:9"], {1},
     "after 1 s not ready: drone01 (not registered), drone02 (not registered)"),
    ("sim: bad world", ["sim", "{d}/bad_world.yml"], {2}, "bogus"),
    ("sim: bad --output", ["sim", "--output", "nohostport"], {2}, "--output"),
    ("sim: unknown autopilot", ["sim", "-n", "1", "--autopilot", "betaflight", "--base-port", "24540"], {2}, "betaflight"),
    ("sim: autopilots not one per drone", ["sim", "-n", "3", "--autopilot", "px4,ardupilot", "--base-port", "24540"], {2},
     "2 autopilots for 3 drones"),
    ("sim: unknown autopilot in the world", ["sim", "{d}/world_autopilot.yml"], {2}, "drones[0].autopilot"),
    ("sim: --param not NAME=VALUE", ["sim", "--param", "MPC_LAND_SPEED"], {2}, "NAME=VALUE"),
    ("sim: --param of another autopilot", ["sim", "-n", "1", "--param", "LAND_SPEED=100", "--base-port", "24540"], {2},
     "--param LAND_SPEED: no px4 vehicle"),
    ("sim: --param speed not above 0", ["sim", "-n", "1", "--param", "MPC_LAND_SPEED=0", "--base-port", "24540"], {2},
     "MPC_LAND_SPEED must be above 0"),
    ("agent: sim:// parameter not a number", ["agent", "--id", "d1", "--fc", "sim://?MPC_LAND_SPEED=fast"], {2}, "fast"),
    ("sensor: missing config", ["sensor", "temperature", "--drone", "d1", "--config", "{d}/missing.yml"], {2}, "missing.yml"),
    ("sensor simulate: no such field sensor", ["sensor", "simulate", "--world", "{d}/gas_world.yml", "--field", "gas99"], {2},
     "no such field sensor (it has: gas07)"),
    ("sensor simulate: a type the world cannot read", ["sensor", "simulate", "--world", "{d}/gas_world.yml", "--drone", "d2",
                                                       "--type", "smoke"], {2}, "it reads: gas, temperature"),
    ("sensor simulate: --drone without --type", ["sensor", "simulate", "--world", "{d}/gas_world.yml", "--drone", "d1"], {2},
     "d1 carries gas, sonar"),
    ("sensor simulate: both a drone and a field", ["sensor", "simulate", "--world", "{d}/gas_world.yml", "--drone", "d1",
                                                   "--type", "gas", "--field", "gas07"], {2}, "not both"),
    ("sensor simulate: bad world", ["sensor", "simulate", "--world", "{d}/bad_world.yml", "--field", "x"], {2}, "bogus"),
    ("sensor: bad endpoint", ["sensor", "temperature", "--drone", "d1", "--connect", "udp/:"], {2}, "udp/:"),
    ("demo: bad world", ["demo", "--world", "{d}/bad_world.yml", "--until-done"], {2}, "bogus"),
    ("demo: --out is a file", ["demo", "--out", "{d}/a_file", "--until-done"], {2}, "a_file"),
    ("drone list: no ground", ["drone", "list", "--url", DEAD_URL], {1}, "127.0.0.1:9"),
    ("drone list: bad url", ["drone", "list", "--url", "not a url"], {1, 2}, "not a url"),
    ("mission list: no ground", ["mission", "list", "--url", DEAD_URL], {1}, "127.0.0.1:9"),
    ("mission submit: no ground", ["mission", "submit", "--url", DEAD_URL, EXAMPLE], {1}, "127.0.0.1:9"),
    ("logs: no ground", ["logs", "--url", DEAD_URL], {1}, "127.0.0.1:9"),
    ("replay: not a recording", ["replay", "{d}/junk.mcap"], {2}, "not an MCAP recording"),
    ("replay: no such file", ["replay", "{d}/missing.mcap"], {2}, "missing.mcap"),
    ("record --recover: not a recording", ["record", "--recover", "{d}/junk.mcap"], {2}, "not an MCAP recording"),
    ("plot: not a recording", ["plot", "{d}/junk.mcap"], {2}, "not an MCAP recording"),
    ("unknown command", ["fly"], {2}, "fly"),
]


@pytest.mark.parametrize(("argv", "codes", "names"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_user_error_is_one_line_and_an_exit_code(files: Path, argv: list[str], codes: set[int], names: str) -> None:
    args = [a.replace("{d}", str(files)) for a in argv]
    result = subprocess.run(fleet_command(*args), capture_output=True, text=True, timeout=60,
                            stdin=subprocess.DEVNULL, cwd=Path(__file__).parent.parent)
    output = result.stdout + result.stderr
    assert "Traceback" not in output, output
    assert result.returncode in codes, f"exit {result.returncode}: {output}"
    last = result.stderr.strip().splitlines()[-1] if result.stderr.strip() else ""
    assert names.replace("{d}", str(files)) in last, f"the last line should name {names!r}: {result.stderr}"
    assert ".rs:" not in output, f"a Rust source path leaked: {output}"


@pytest.mark.parametrize(("flags", "level"), [([], "INFO"), (["-v"], "DEBUG")])
def test_verbosity_of_a_service(flags: list[str], level: str) -> None:
    """Services (agent, ground, sim, demo, sensor) log at INFO by default; -v adds
    Fleet's debug lines, -vv also the libraries'. Clients log warnings only; -v, -vv add."""
    from dronefleet.cli import log_levels

    assert log_levels("ground", len(flags))[0] == level


def test_verbosity_levels_differ() -> None:
    from dronefleet.cli import log_levels

    assert [log_levels("drone", v) for v in (0, 1, 2)] == [
        ("WARNING", "WARNING"), ("INFO", "WARNING"), ("DEBUG", "DEBUG")]
    assert [log_levels("ground", v) for v in (0, 1, 2)] == [
        ("INFO", "WARNING"), ("DEBUG", "WARNING"), ("DEBUG", "DEBUG")]


def test_pki_dir_implies_tls_unless_the_config_says_otherwise(tmp_path: Path) -> None:
    from dronefleet.cli import security_with_pki

    assert security_with_pki(None, None) is None
    assert security_with_pki(None, "/pki") == {"pki_dir": "/pki", "tls": True}
    config = tmp_path / "agent.yml"
    config.write_text("security: {tls: false, window_s: 10, pki_dir: /elsewhere}\n")
    assert security_with_pki(config, "/pki") == {"pki_dir": "/pki", "tls": False, "window_s": 10}
