"""What a drone is (SPEC §2 About) as pure logic: declarations in the agent's config,
readings held to them at the ground, kinds and roles in assignment (issue 35)."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from dronefleet.agent.config import AgentConfig
from dronefleet.ground.config import GroundConfig
from dronefleet.ground.registry import DROPPED_LOG_MS, Registry
from dronefleet.mission.lifecycle.assignment import (
    AnyDrone,
    AnyRelay,
    ById,
    ByKind,
    ByRole,
    BySensors,
    Candidate,
    Near,
    Unfulfilled,
    choose,
    replacement,
)
from dronefleet.schemas.about import About, FieldSpec, SensorDeclaration, may_relay, reading_fault, relay_disagreement
from dronefleet.schemas.codec import decode_about, decode_sensor, encode
from dronefleet.schemas.config_loading import ConfigError, load_config
from dronefleet.schemas.telemetry import SensorReading
from tests.ground.test_registry import lines, telem

GAS = SensorDeclaration(type="gas", fields={"co_ppm": FieldSpec(unit="ppm", min=0, max=1000),
                                            "no2_ppb": FieldSpec(unit="ppb", min=0, max=500)})
TEMP = SensorDeclaration(type="temperature", unit="degC", min=-40, max=150)


def gas(**fields: object) -> SensorReading:
    return SensorReading(drone_id="drone01", timestamp=0, type="gas", fields=fields)  # type: ignore[arg-type]


def test_the_spec_about_and_a_multi_field_reading_decode_as_written() -> None:
    about = decode_about(b'{"drone_id": "drone01", "timestamp": 1, "kind": "x500-quad", "roles": ["survey", "relay"],'
                         b' "sensors": [{"type": "gas", "fields": {"co_ppm": {"unit": "ppm", "min": 0, "max": 1000}}}]}')
    assert about.kind == "x500-quad" and about.roles == ["survey", "relay"]
    assert about.sensors[0].fields["co_ppm"] == FieldSpec(unit="ppm", min=0, max=1000)
    defaults = decode_about(b'{"drone_id": "d", "timestamp": 1}')
    assert defaults.kind == "multicopter" and defaults.roles == ["survey"] and defaults.sensors == []
    reading = decode_sensor(b'{"drone_id": "drone01", "timestamp": 1, "type": "gas", "fields": {"co_ppm": 12.5, "no2_ppb": 31.0}}')
    assert reading.value is None and reading.fields == {"co_ppm": 12.5, "no2_ppb": 31.0}
    assert msgspec.json.decode(encode(about))["roles"] == ["survey", "relay"]


@pytest.mark.parametrize(("reading", "fault"), [
    (gas(co_ppm=12.5, no2_ppb=31.0), None),
    (gas(co_ppm=12.5), None),  # a field it did not carry this time is not outside
    (gas(co_ppm=1200.0), "gas.co_ppm 1200 is outside [0, 1000]"),
    (gas(co_ppm=-1), "gas.co_ppm -1 is outside [0, 1000]"),
    (gas(so2=3.0), "unknown field gas.so2 (declared: co_ppm, no2_ppb)"),
    (gas(co_ppm="high"), "gas.co_ppm is 'high', not a number"),
    (gas(co_ppm=True), "gas.co_ppm is True, not a number"),
    (SensorReading(drone_id="drone01", timestamp=0, type="gas", value=3.0), "gas is declared with fields co_ppm, no2_ppb; the reading has none"),
    (SensorReading(drone_id="drone01", timestamp=0, type="temperature", value=51.9), None),
    (SensorReading(drone_id="drone01", timestamp=0, type="temperature", value=151.0), "temperature value 151 is outside [-40, 150]"),
    (SensorReading(drone_id="drone01", timestamp=0, type="temperature", value=None), "temperature value is None, not a number"),
    (SensorReading(drone_id="drone01", timestamp=0, type="humidity", value=3.0), "undeclared sensor type 'humidity' (declared: gas, temperature)"),
])
def test_a_reading_is_held_to_its_declaration(reading: SensorReading, fault: str | None) -> None:
    assert reading_fault(reading, [GAS, TEMP]) == fault


def test_a_field_declared_without_unit_or_range_reads_a_word_or_a_flag() -> None:
    declared = [SensorDeclaration(type="gas", fields={"co_ppm": FieldSpec(unit="ppm"), "status": FieldSpec(), "alarm": FieldSpec()})]
    assert reading_fault(gas(co_ppm=3.0, status="ok", alarm=False), declared) is None
    assert reading_fault(gas(co_ppm="ok"), declared) == "gas.co_ppm is 'ok', not a number"


def test_nothing_declared_holds_nothing() -> None:
    assert reading_fault(SensorReading(drone_id="d", timestamp=0, type="anything", value="x"), []) is None


@pytest.mark.parametrize(("yaml_text", "error"), [
    ("roles: [survey, pilot]\n", "roles"),
    ("roles: []\n", "roles"),
    ("roles: [relay, relay]\n", "relay listed twice"),
    ("sensors: [{type: gas, fields: {co ppm: {unit: ppm}}}]\n", "field names must be identifiers"),
    ("sensors: [{type: gas, fields: {co_ppm: {unit: ppm, min: 5, max: 1}}}]\n", "min 5 is above max 1"),
    ("sensors: [{type: gas, feilds: {}}]\n", "feilds"),
    ("sensors: [{type: gas}, {type: gas}]\n", "gas listed twice"),
    ("sensors: [{type: 'a/b'}]\n", "sensor type 'a/b'"),
    ("kind: ''\n", "kind"),
])
def test_bad_about_keys_in_the_agent_config_stop_it_at_start(tmp_path: Path, yaml_text: str, error: str) -> None:
    path = tmp_path / "agent.yml"
    path.write_text(yaml_text)
    with pytest.raises(ConfigError) as caught:
        load_config(AgentConfig, path, {})
    assert error in str(caught.value) and "agent.yml" in str(caught.value), caught.value


def test_the_agent_config_takes_kind_roles_and_sensors(tmp_path: Path) -> None:
    path = tmp_path / "agent.yml"
    path.write_text("kind: x500-quad\nroles: [survey, relay]\n"
                    "sensors: [{type: gas, fields: {co_ppm: {unit: ppm, min: 0, max: 1000}}}, {type: temperature, unit: degC}]\n")
    config = load_config(AgentConfig, path, {})
    assert config.kind == "x500-quad" and config.roles == ["survey", "relay"]
    assert config.sensors[0].fields["co_ppm"].max == 1000 and config.sensors[1].unit == "degC"
    default = AgentConfig()
    assert default.kind == "multicopter" and default.roles == ["survey"] and default.sensors == []


def test_the_registry_keeps_what_a_drone_says_it_is_and_logs_a_change() -> None:
    reg = Registry(GroundConfig())
    about = About(drone_id="drone01", timestamp=0, kind="x500-quad", roles=["survey", "relay"], sensors=[GAS])
    assert reg.on_about(about, 0) == []  # before its first telemetry: kept for its registration
    events = reg.on_telemetry(telem(), 1000)
    assert "INFO Declares kind x500-quad, roles survey, relay, sensors gas (co_ppm ppm, no2_ppb ppb)" in lines(events)
    info = reg.info("drone01")
    assert info.kind == "x500-quad" and info.roles == ["survey", "relay"] and info.sensors_declared == [GAS]
    assert reg.on_about(msgspec.structs.replace(about, timestamp=5), 2000) == []  # the same again: nothing
    changed = reg.on_about(msgspec.structs.replace(about, roles=["auxiliary"]), 3000)
    assert "INFO Changed what it declares: kind x500-quad, roles auxiliary, sensors gas (co_ppm ppm, no2_ppb ppb)" in lines(changed)
    assert reg.info("drone01").roles == ["auxiliary"]
    reg.on_telemetry(telem("drone02"), 1000)
    assert reg.info("drone02").kind is None and reg.info("drone02").roles is None  # never said


def test_a_reading_outside_the_declaration_is_dropped_and_logged_once_per_period() -> None:
    reg = Registry(GroundConfig())
    reg.on_telemetry(telem(), 0)
    reg.on_about(About(drone_id="drone01", timestamp=0, sensors=[GAS]), 0)
    assert reg.drop_reading(gas(co_ppm=10.0), 100) is None
    first = reg.drop_reading(gas(co_ppm=5000.0), 200)
    assert lines(first or []) == ["WARN Dropped a gas reading outside its declaration: gas.co_ppm 5000 is outside [0, 1000]"]
    assert reg.drop_reading(gas(co_ppm=6000.0), 300) == []  # dropped, not logged again at once
    assert reg.drop_reading(gas(co_ppm=7000.0), 400) == []
    again = reg.drop_reading(gas(co_ppm=8000.0), 200 + DROPPED_LOG_MS)
    assert lines(again or []) == ["WARN Dropped a gas reading outside its declaration: gas.co_ppm 8000 is outside [0, 1000] "
                                  "(2 more dropped since)"]


def test_the_relay_role_and_the_certificate_must_agree_on_a_secured_mesh() -> None:
    assert may_relay(None, "d1", ["survey"])  # an open mesh: anyone may carry
    assert may_relay(frozenset({"d1"}), "d1", None)  # About not heard: the certificate alone
    assert may_relay(frozenset({"d1"}), "d1", ["survey", "relay"])
    assert not may_relay(frozenset({"d1"}), "d1", ["survey"])
    assert not may_relay(frozenset(), "d1", ["relay"])
    assert "does not declare the relay role" in (relay_disagreement(frozenset({"d1"}), "d1", ["survey"]) or "")
    assert "not issued --role relay" in (relay_disagreement(frozenset(), "d1", ["relay"]) or "")
    assert relay_disagreement(None, "d1", ["relay"]) is None
    reg = Registry(GroundConfig(), relays=frozenset({"drone01"}))
    reg.on_about(About(drone_id="drone01", timestamp=0, roles=["survey"]), 0)
    assert any("WARN Relay role: its certificate lets it relay" in line for line in lines(reg.on_telemetry(telem(), 0)))


AUX = Candidate("aux", battery=1.0, lat=40.6335, lon=-8.6608, roles=frozenset({"auxiliary"}))
SURVEYOR = Candidate("surveyor", frozenset({"gas"}), battery=0.5, lat=40.6400, lon=-8.6608, kind="x500")
RELAYER = Candidate("relayer", battery=0.3, lat=40.6500, lon=-8.6608, roles=frozenset({"survey", "relay"}))
POOL = [AUX, SURVEYOR, RELAYER]


@pytest.mark.parametrize(("request_", "expected"), [
    (AnyDrone(), "relayer"),  # the fewest sensors, never the auxiliary one (most battery, no sensors)
    (Near(40.6335, -8.6608), "surveyor"),  # the auxiliary one stands there: not picked by proximity
    (ById("aux"), "aux"),
    (ByRole("auxiliary"), "aux"),
    (ByRole("relay"), "relayer"),
    (ByKind("x500"), "surveyor"),
    (AnyRelay(), "relayer"),  # declared for it first
])
def test_an_auxiliary_drone_is_picked_only_by_id_role_or_as_a_relay(request_: object, expected: str) -> None:
    assert choose(request_, POOL).drone_id == expected  # type: ignore[arg-type]


def test_any_relay_takes_an_auxiliary_drone_before_a_surveyor_and_replacement_prefers_it() -> None:
    assert choose(AnyRelay(), [AUX, SURVEYOR]).drone_id == "aux"
    assert replacement(40.6400, -8.6608, [SURVEYOR, AUX]) == "aux"  # farther, but auxiliary
    assert replacement(40.6400, -8.6608, [SURVEYOR, RELAYER]) == "surveyor"  # none auxiliary: the closest


def test_only_auxiliary_drones_left_fails_any_drone_with_requirements_naming_them() -> None:
    with pytest.raises(Unfulfilled) as caught:
        choose(AnyDrone(), [AUX])
    assert "only auxiliary drones are free (aux)" in str(caught.value)
    with pytest.raises(Unfulfilled):  # nor by its sensors
        choose(BySensors(frozenset({"gas"})), [Candidate("auxgas", frozenset({"gas"}), roles=frozenset({"auxiliary"}))])


def test_a_world_drones_agent_config_carries_its_sensor_declarations(tmp_path: Path) -> None:
    """`fleet sim --agents` and `fleet demo`: each agent's config is the given one plus
    what the world says the drone carries; a drone with no sensor keeps the given file."""
    from dronefleet.sim.agent_command import drone_agent_config
    from dronefleet.sim.world import load_world

    world = load_world(Path(__file__).parents[2] / "examples" / "worlds" / "gas_alarm.yml")
    base = tmp_path / "agent.yml"
    base.write_text("telemetry_rate_ms: 250\n")
    by_id = {spec.id: spec for spec in world.spawn()}
    written = drone_agent_config(base, world, by_id["drone02"], tmp_path / "out")
    assert written is not None and written != base
    config = load_config(AgentConfig, written, {})
    assert config.telemetry_rate_ms == 250
    assert [(d.type, sorted(d.fields)) for d in config.sensors] == [("gas", ["co_ppm"])]
    assert drone_agent_config(base, world, by_id["drone04"], tmp_path / "out") == base  # no sensor
    assert load_config(AgentConfig, drone_agent_config(None, world, by_id["drone01"], tmp_path / "out"), {}).sensors[0].unit == "degC"
