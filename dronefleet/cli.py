"""`fleet`: the command line. Thin: parse, load a strict config, call into the package.

Only this module configures logging output. Exit codes: 0 done, 1 runtime failure
(e.g. flight controller unreachable), 2 bad usage or configuration. The group is the
one boundary for user errors: a FleetError (or a file that cannot be read or written)
that reaches it ends as one line `fleet: …` and its exit code, never a traceback.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import get_args

import click

from dronefleet.cli_kit import (
    ENDPOINT,
    HOST_PORT,
    LIBRARIES,
    NAME_VALUE,
    PKI_DIR_HELP,
    FleetGroup,
    checked_id,
    drone_id_option,
    fail,
    log_levels,
    run_async,
    secured_client,
    security_with_pki,
    with_pki,
)
from dronefleet.schemas.errors import ConfigError
from dronefleet.sim.fault_kinds import FaultKind


@click.group(cls=FleetGroup, help="Fleets of connected drones: the on-board agent, the ground station, missions, "
             "simulation. `fleet COMMAND --help` for each; the documentation (docs/, `make docs`) for the whole picture.")
@click.option("-v", "--verbose", count=True,
              help="More log output: -v Fleet's next level (services: debug; clients: info), -vv debug for everything.")
@click.pass_context
def main(ctx: click.Context, verbose: int) -> None:
    fleet, libraries = log_levels(ctx.invoked_subcommand, verbose)
    logging.basicConfig(level=fleet, format="%(asctime)s %(levelname)-7s %(name)s: %(message)s", stream=sys.stderr)
    for name in LIBRARIES:
        logging.getLogger(name).setLevel(libraries)


@main.command()
@click.option("--id", "drone_id", required=True, callback=drone_id_option, help="Drone identifier, e.g. drone01.")
@click.option("--config", "config_path", type=click.Path(path_type=Path, dir_okay=False), help="Agent YAML config.")
@click.option("--fc", help="Flight controller URL: sim, udp://:14540, serial:///dev/ttyACM0[:baud], tcp://host:port.")
@click.option("--connect", multiple=True, type=ENDPOINT, help="Zenoh endpoint of the ground router (repeatable), e.g. tcp/192.168.1.10:7447.")
@click.option("--listen", multiple=True, type=ENDPOINT, help="Zenoh endpoint of this agent's own router (repeatable; default tcp/0.0.0.0:7448): on-board programs and neighbouring drones connect here.")
@click.option("--mesh-interface", help="Radio interface on which to find neighbouring drones (multicast scouting), e.g. wlan0.")
@click.option("--telemetry-rate-ms", type=int, help="Telemetry period in milliseconds.")
@click.option("--state-dir", help="Where task bundle records outlive the agent; default ~/.local/state/fleet/<id>.")
@click.option("--pki-dir", type=click.Path(file_okay=False, exists=True), help=PKI_DIR_HELP)
@click.option("--kind", help="What the drone is (About `kind`, free text), e.g. x500-quad; default multicopter.")
@click.option("--role", "roles", multiple=True, type=click.Choice(["survey", "relay", "auxiliary"]),
              help="Its roles (repeatable; About `roles`); default survey.")
def agent(drone_id: str, config_path: Path | None, fc: str | None, connect: tuple[str, ...], listen: tuple[str, ...],
          mesh_interface: str | None, telemetry_rate_ms: int | None, state_dir: str | None, pki_dir: str | None,
          kind: str | None, roles: tuple[str, ...]) -> None:
    """Run the on-drone agent: flight controller <-> Zenoh mesh."""
    from dronefleet.agent.config import AgentConfig, default_state_dir
    from dronefleet.agent.runtime import STOP_GRACE_S, run_agent
    from dronefleet.schemas.config_loading import load_config
    config = load_config(
        AgentConfig, config_path,
        {"fc": fc, "connect": list(connect) or None, "listen": list(listen) or None,
         "mesh_interface": mesh_interface, "telemetry_rate_ms": telemetry_rate_ms, "state_dir": state_dir,
         "security": security_with_pki(config_path, pki_dir), "kind": kind, "roles": list(roles) or None},
    )
    if config.state_dir is None:
        import msgspec

        config = msgspec.structs.replace(config, state_dir=default_state_dir(drone_id))
    run_async(run_agent(drone_id, config), stop_grace_s=STOP_GRACE_S)


@main.command()
@click.option("--config", "config_path", type=click.Path(path_type=Path, dir_okay=False), help="Ground YAML config.")
@click.option("--listen", multiple=True, type=ENDPOINT, help="Zenoh endpoint the router listens on (repeatable); default tcp/0.0.0.0:7447.")
@click.option("--http-port", type=click.IntRange(0, 65535), help="HTTP API port; default 8001.")
@click.option("--data-dir", help="Where the event log and mission records live; default ~/.local/share/fleet.")
@click.option("--pki-dir", type=click.Path(file_okay=False, exists=True), help=PKI_DIR_HELP)
@click.option("--id", "ground_id", help="This ground's id among several on one mesh (config ground_id; default the host name).")
@click.option("--priority", type=click.IntRange(-1000, 1000), help="Rank among the grounds: the highest is active (config priority; default 0).")
@click.option("--connect", multiple=True, type=ENDPOINT, help="Zenoh endpoint of another ground's router to join (repeatable), e.g. tcp/192.168.1.10:7447.")
@click.option("--observer", is_flag=True, default=None,
              help="Watch only: see every drone, mission and log, never become active or command (config role: observer).")
def ground(config_path: Path | None, listen: tuple[str, ...], http_port: int | None, data_dir: str | None,
           pki_dir: str | None, ground_id: str | None, priority: int | None, connect: tuple[str, ...],
           observer: bool | None) -> None:
    """Run the ground station: Zenoh router, fleet registry, event log, HTTP API. Several on
    one mesh: the highest priority is active, the others standby; an observer only watches
    (SPEC §14)."""
    from dronefleet.compose import run_ground
    from dronefleet.ground.config import GroundConfig
    from dronefleet.schemas.config_loading import load_config

    config = load_config(
        GroundConfig, config_path, {"listen": list(listen) or None, "http_port": http_port, "data_dir": data_dir,
                                    "security": security_with_pki(config_path, pki_dir), "ground_id": ground_id,
                                    "priority": priority, "connect": list(connect) or None,
                                    "role": "observer" if observer else None}
    )
    run_async(run_ground(config, lambda line: click.echo(line)))


@main.command()
@click.argument("keyexpr", default="**")
@click.option("--connect", multiple=True, type=ENDPOINT, default=["tcp/127.0.0.1:7447"], show_default=True, help="Zenoh endpoint (repeatable).")
@click.option("--count", type=click.IntRange(1), help="Exit after this many samples.")
@with_pki
def sub(keyexpr: str, connect: tuple[str, ...], count: int | None, pki_dir: Path | None, cert_name: str) -> None:
    """Print live traffic: one line per sample, key and compact JSON."""
    from dronefleet.bus.tap import tap

    extra = secured_client(pki_dir, cert_name, list(connect))
    run_async(tap(keyexpr, list(connect), lambda line: click.echo(line), count, extra))


@main.command()
@click.argument("world", required=False, type=click.Path(path_type=Path, dir_okay=False, exists=True))
@click.option("-n", "count", type=click.IntRange(1, 100), help="Number of vehicles (default: the world's, else 1).")
@click.option("--agents", is_flag=True, help="Also start one `fleet agent` per vehicle.")
@click.option("--connect", multiple=True, type=ENDPOINT, help="Zenoh endpoint for the agents (repeatable).")
@click.option("--agent-config", type=click.Path(path_type=Path, dir_okay=False, exists=True), help="Config file passed to each agent.")
@click.option("--base-port", type=click.IntRange(1025, 65000), default=14540, show_default=True, help="Vehicle i sends MAVLink to 127.0.0.1:BASE+i; fault control listens on BASE-1.")
@click.option("--output", "outputs", multiple=True, type=HOST_PORT, help="Extra MAVLink output HOST:PORT for every vehicle (e.g. a GCS on 14550).")
@click.option("--radio", is_flag=True, help="Emulated radio: each drone in its own network namespace, loss following the distances (needs root).")
@click.option("--ground-port", type=click.IntRange(1, 65535), default=7447, show_default=True, help="With --radio: the port of `fleet ground` the agents connect to at the laptop's radio address.")
@click.option("--autopilot", "autopilots", help="px4 or ardupilot for every vehicle, or one per vehicle in order (px4,ardupilot,…); default: each drone's `autopilot` in the world file, else px4.")
@click.option("--param", "params", multiple=True, type=NAME_VALUE, help="Set an autopilot parameter at start on every vehicle whose autopilot has it, as a ground station would (repeatable), e.g. MPC_LAND_SPEED=1.2 or LAND_SPEED=100.")
def sim(world: Path | None, count: int | None, agents: bool, connect: tuple[str, ...], agent_config: Path | None, base_port: int,
        outputs: tuple[tuple[str, int], ...], radio: bool, ground_port: int, autopilots: str | None,
        params: tuple[tuple[str, float], ...]) -> None:
    """Run PX4-like or ArduCopter-like MAVLink vehicles (UDP 14540+i), optionally with their agents."""
    from dronefleet.sim.fleet_sim import run_sim
    from dronefleet.sim.world import load_world

    loaded = load_world(world)
    try:
        run_async(run_sim(
            loaded, count, base_port=base_port, agents=agents, connect=list(connect),
            agent_config=agent_config, extra_outputs=list(outputs), radio=radio, ground_port=ground_port,
            out=lambda line: click.echo(line), autopilots=[a.strip() for a in autopilots.split(",")] if autopilots else None,
            params=dict(params),
        ))
    except OSError as exc:
        fail(f"cannot bind the simulator's ports: {exc}")


@main.command()
@click.argument("drone")
@click.argument("kind", type=click.Choice([*get_args(FaultKind), "status"]))  # the world file's faults, one list
@click.argument("value", required=False)
@click.option("--control", type=HOST_PORT, default="127.0.0.1:14539", show_default=True, help="Control channel: `fleet sim` (base port - 1) or an agent on `--fc sim://?control=PORT`.")
def fault(drone: str, kind: str, value: str | None, control: tuple[str, int]) -> None:
    """Inject a fault into a vehicle of a running `fleet sim`."""
    from dronefleet.sim.faults import send_fault

    try:
        reply = run_async(send_fault(drone, kind, value, control))
    except TimeoutError:
        fail(f"no `fleet sim` answers on {control[0]}:{control[1]}")
    if not reply or not reply.get("ok"):
        fail(str(reply.get("error") if reply else "no reply"))
    for line in (reply.get("status") or {}).values():
        click.echo(line)


@main.group()
def sensor() -> None:
    """Sensors on the mesh: simulated ones beside a drone's agent, and field sensors."""


@sensor.command("temperature")
@click.option("--drone", "drone_id", callback=drone_id_option, help="The drone whose telemetry gives the position (or drone_id in the config).")
@click.option("--config", "config_path", type=click.Path(path_type=Path, dir_okay=False), help="Heat field YAML: rate_ms, environment_temp, heat_sources [{lat, lon, radius, temp}].")
@click.option("--connect", multiple=True, type=ENDPOINT, default=["tcp/127.0.0.1:7447"], show_default=True, help="Zenoh endpoint (repeatable).")
@click.option("--rate-ms", type=int, help="Publish period in milliseconds (default 200).")
@click.option("--count", type=click.IntRange(1), help="Exit after publishing this many readings.")
@click.option("--pki-dir", type=click.Path(file_okay=False, exists=True, path_type=Path),
              help="On a secured mesh (SPEC §9): the directory with ca.pem and the drone's NAME.pem/NAME.key; endpoints tls/…")
@click.option("--name", "cert_name", help="The certificate to show, with --pki-dir (default: the drone id).")
def sensor_temperature(drone_id: str | None, config_path: Path | None, connect: tuple[str, ...], rate_ms: int | None,
                       count: int | None, pki_dir: Path | None, cert_name: str | None) -> None:
    """Thesis example 21: the temperature where DRONE is, from a heat field, on drone/<id>/sensor/temperature."""
    from dronefleet.schemas.config_loading import load_config
    from dronefleet.sim.heat_field import HeatConfig
    from dronefleet.sim.sensors import run_temperature_sensor

    config = load_config(HeatConfig, config_path, {"drone_id": drone_id, "rate_ms": rate_ms})
    if config.drone_id is None:
        raise ConfigError("give --drone ID (or drone_id in the config)")
    checked_id(config.drone_id, f"{config_path}: drone_id")
    extra = secured_client(pki_dir, cert_name or config.drone_id, list(connect))
    run_async(run_temperature_sensor(config.drone_id, config, list(connect), lambda line: click.echo(line), count, extra))


@sensor.command("simulate")
@click.option("--world", "world_path", required=True, type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="The world file whose heat field and `fields:` (and `field_sensors:`) are read.")
@click.option("--drone", "drone_id", callback=drone_id_option, help="A sensor on this drone: read where its telemetry puts it.")
@click.option("--type", "kind", help="The sensor type on the drone: temperature, or a type of the world's `fields:` (e.g. gas).")
@click.option("--field", "field_id", help="Instead: the world's field sensor with this id, where the world places it.")
@click.option("--connect", multiple=True, type=ENDPOINT, default=["tcp/127.0.0.1:7447"], show_default=True,
              help="Zenoh endpoint: the drone's agent or the ground (repeatable).")
@click.option("--count", type=click.IntRange(1), help="Exit after publishing this many readings.")
@click.option("--pki-dir", type=click.Path(file_okay=False, exists=True, path_type=Path),
              help="On a secured mesh (SPEC §9): ca.pem and NAME.pem/NAME.key (the drone's, or the field sensor's issued --role sensor).")
@click.option("--name", "cert_name", help="The certificate to show, with --pki-dir (default: the drone or sensor id).")
def sensor_simulate(world_path: Path, drone_id: str | None, kind: str | None, field_id: str | None, connect: tuple[str, ...],
                    count: int | None, pki_dir: Path | None, cert_name: str | None) -> None:
    """Any simulated sensor a world file describes, as a program on the mesh.

    On a drone (--drone ID --type T): drone/<id>/sensor/<T>, the world's heat field
    (temperature) or its `fields:` of type T where the drone's telemetry puts it. A field
    sensor (--field ID): sensor/<id>/<type> with its position and liveliness token.
    """
    from dronefleet.sim.sensors import run_sensor_program, world_sensor_program
    from dronefleet.sim.world import load_world

    if drone_id is not None and field_id is not None:
        raise ConfigError("give --drone ID --type TYPE or --field ID, not both")
    world = load_world(world_path)
    program, about = world_sensor_program(world, drone_id=drone_id, kind=kind, field_id=field_id)
    name = field_id or drone_id
    assert name is not None
    extra = secured_client(pki_dir, cert_name or name, list(connect))
    click.echo(about)
    run_async(run_sensor_program(program, list(connect), lambda line: click.echo(line), count, extra))


@sensor.command("publish")
@click.option("--id", "sensor_id", required=True, help="The field sensor's id (its key: sensor/<id>/<type>).")
@click.option("--type", "sensor_type", required=True, help="What it measures, e.g. gas or temperature.")
@click.option("--at", "at", required=True, help="Where it stands: LAT,LON[,ALT] (degrees, metres AMSL).")
@click.option("--value", type=float, help="A one-value reading (else FIELD=NUMBER pairs, else JSON lines on stdin).")
@click.option("--unit", default="", help="The value's unit, e.g. degC.")
@click.option("--connect", multiple=True, type=ENDPOINT, default=["tcp/127.0.0.1:7447"], show_default=True,
              help="Zenoh endpoint of the ground or a drone's agent (repeatable).")
@click.option("--pki-dir", type=click.Path(file_okay=False, exists=True, path_type=Path),
              help="On a secured mesh (SPEC §9): ca.pem and the sensor's NAME.pem/NAME.key (issued --role sensor); endpoints tls/…")
@click.option("--name", "cert_name", help="The certificate to show, with --pki-dir (default: the sensor id).")
@click.argument("fields", nargs=-1)
def sensor_publish(sensor_id: str, sensor_type: str, at: str, value: float | None, unit: str, connect: tuple[str, ...],
                   pki_dir: Path | None, cert_name: str | None, fields: tuple[str, ...]) -> None:
    """A field sensor (not on a drone) publishes on sensor/<id>/<type> with its position.

    One reading from FIELDS (co_ppm=12.5 no2_ppb=31) or --value; with neither, one per
    JSON line on stdin ({"co_ppm": 12.5}, {"value": 21.5}, "at": [lat, lon, alt] moves it)
    until end of input: a script beside a real sensor pipes into it.
    """
    from dronefleet.sim.sensor_publisher import parse_at, parse_fields, run_publish

    position = parse_at(at)
    given = parse_fields(fields)
    if value is not None and given:
        raise ConfigError("give --value or FIELD=NUMBER pairs, not both")
    extra = secured_client(pki_dir, cert_name or sensor_id, list(connect))
    sent = run_async(run_publish(sensor_id, sensor_type, position, value, given, unit, list(connect), extra,
                                 lambda line: click.echo(line)))
    if not sent:
        fail("nothing published", 1)


@main.command()
@click.option("--port", type=click.IntRange(1, 65535), default=7447, show_default=True, help="Port of the demo ground's Zenoh router.")
@click.option("--http-port", type=click.IntRange(1, 65535), default=8001, show_default=True, help="Port of the demo ground's HTTP API.")
@click.option("--world", type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="World file (drones, sensors, heat sources); default examples/worlds/fire.yml.")
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False), default=Path("demo-out"), show_default=True,
              help="Where result.json, the plots, the ground's log and the agents' logs go.")
@click.option("--until-done", is_flag=True, help="Exit when the mission ends: 0 if it finished with success, else 1.")
@click.option("--max-time", "max_time_s", type=click.FloatRange(1, 86_400), default=600, show_default=True,
              help="Cancel the mission and exit 1 if it runs longer than this (s).")
@click.option("--radio", is_flag=True,
              help="Drones on the emulated radio: each agent and its sensors in its own network namespace, "
                   "loss following the distances (needs root; SPEC §8).")
@click.option("--mission", "mission", type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="The mission script to fly; default examples/fire_tracing.py (e.g. examples/gas_alarm.py "
                   "with --world examples/worlds/gas_alarm.yml).")
def demo(port: int, http_port: int, world: Path | None, out_dir: Path, until_done: bool, max_time_s: float,
         radio: bool, mission: Path | None) -> None:
    """A ground and the world's simulated drones (and field sensors) fly a mission
    (default: fire tracing), with progress and plots."""
    from dronefleet.demo import DEFAULT_WORLD, SCRIPT, Demo, DemoOptions

    if not logging.getLogger().isEnabledFor(logging.DEBUG):  # the demo prints its own progress; -v shows the rest
        for name in ("dronefleet.ground", "dronefleet.mission", "dronefleet.agent", "dronefleet.bus", "dronefleet.sim", "matplotlib"):
            logging.getLogger(name).setLevel(logging.WARNING)
    options = DemoOptions(
        port=port, http_port=http_port, world=world or DEFAULT_WORLD, out_dir=out_dir,
        until_done=until_done, max_time_s=max_time_s, radio=radio, mission=mission or SCRIPT,
    )
    run = Demo(options, lambda line: click.echo(line))
    code = run_async(run.run())
    if code is None:  # Ctrl-C or SIGTERM: fine once the mission has succeeded
        code = 0 if run.mission_ok else 130
    sys.exit(code)


def _add_http_clients() -> None:
    from dronefleet.ground.cli import drone, logs
    from dronefleet.mission_cli import mission
    from dronefleet.pki import pki
    from dronefleet.recording_cli import plot, record, replay
    from dronefleet.tiles_cli import tiles

    main.add_command(tiles)
    main.add_command(drone)
    main.add_command(logs)
    main.add_command(mission)
    for command in (record, replay, plot, pki):
        main.add_command(command)


_add_http_clients()
