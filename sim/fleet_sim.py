"""`fleet sim`: N PX4-like (or ArduCopter-like) MAVLink vehicles on UDP 14540+i,
optionally with agents.

Like PX4 SITL, vehicle i sends to 127.0.0.1:(base+i) and answers whoever talks to
it. A one-line status is printed per vehicle whenever its mode, arming, landed
state or link changes. Faults come from the world file (`faults: [{at_s, fault}]`)
or the control channel: JSON datagrams on 127.0.0.1:(base-1), e.g.
`{"drone": "drone01", "fault": "rc_takeover"}` (see `fleet fault`). Everything
started here stops on Ctrl-C/SIGTERM.

With `radio`, each drone lives in its own network namespace on the emulated radio
(sim/radio_field.py): its MAVLink socket is made there (the link between autopilot
and companion computer stays on the drone), its agent and sensor programs run
there, and the loss between every pair of nodes follows the simulated distances.
"""

from __future__ import annotations

import asyncio
import logging
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import msgspec

from dronefleet.schemas.config_loading import Security, read_yaml
from dronefleet.schemas.errors import ConfigError
from dronefleet.sim.agent_command import agent_command, drone_agent_config, sensor_command, world_file
from dronefleet.sim.autopilot_params import BY_AUTOPILOT, check
from dronefleet.sim.faults import FaultChannel, apply_fault, open_fault_channel
from dronefleet.sim.mavlink_endpoint import AUTOPILOTS, MavlinkVehicle, param_names
from dronefleet.sim.radio import Spot3, spot_of
from dronefleet.sim.radio_field import RadioField
from dronefleet.sim.radio_net import die_with_parent, socket_in_netns
from dronefleet.sim.scratch import scratch_dir
from dronefleet.sim.world import DroneSpec, World

log = logging.getLogger(__name__)
PX4_SITL_BASE = 14540
PX4_SITL_LOCAL = 14580  # PX4 SITL sends from 14580+i
# An agent on the radio may take seconds to close its Zenoh session (links to lossy
# neighbours are flushed first); past this, together, they are killed.
CHILDREN_STOP_S = 10.0


@dataclass
class SimVehicle:
    spec: DroneSpec
    endpoint: MavlinkVehicle
    port: int  # where its MAVLink goes (the agent listens here)


def _find(vehicles: dict[str, SimVehicle], name: str) -> SimVehicle:
    if name not in vehicles:
        raise ValueError(f"unknown drone {name!r} (have {', '.join(vehicles)})")
    return vehicles[name]


def agent_security(agent_config: Path | None) -> Security:
    """The `security` section of the agents' config: on the radio it decides the scheme
    of every endpoint the sim hands its agents and sensors."""
    section = read_yaml(agent_config).get("security") if agent_config is not None else None
    try:
        return msgspec.convert(section or {}, Security)
    except msgspec.ValidationError as exc:
        raise ConfigError(f"{agent_config}: security: {str(exc).replace('$.', '')}") from None


def autopilot_of(specs: list[DroneSpec], given: list[str] | None) -> dict[str, str]:
    """Each drone's autopilot: `given` (`--autopilot`: one for all, or one per drone in
    order), else the world file's `autopilot` of the drone, else px4."""
    if given and len(given) not in (1, len(specs)):
        raise ConfigError(f"--autopilot names {len(given)} autopilots for {len(specs)} drones: "
                          "give one for all, or one per drone")
    for make in given or []:
        if make not in AUTOPILOTS:
            raise ConfigError(f"--autopilot {make!r}: expected one of {', '.join(AUTOPILOTS)}")
    return {s.id: (given[0] if len(given) == 1 else given[i]) if given else (s.autopilot or "px4")
            for i, s in enumerate(specs)}


def check_params(params: dict[str, float], autopilots: set[str]) -> None:
    """`--param` names a parameter of at least one of the vehicles' autopilots, with a
    value the vehicle can fly with."""
    known = set().union(*(param_names(a) for a in autopilots))
    unknown = sorted(set(params) - known)
    if unknown:
        raise ConfigError(f"--param {', '.join(unknown)}: no {' or '.join(sorted(autopilots))} vehicle here has it "
                          f"(known: {', '.join(sorted(known))})")
    for name, value in params.items():
        for autopilot in autopilots:
            if name in BY_AUTOPILOT[autopilot]:
                try:
                    check(BY_AUTOPILOT[autopilot], name, value)
                except ValueError as exc:
                    raise ConfigError(f"--param {name}: {exc}") from None


def status_line(v: SimVehicle) -> str:
    veh = v.endpoint.vehicle
    return (
        f"{v.spec.id:<10} sysid {v.endpoint.sysid:<3} udp {v.port:<6} {v.endpoint.mode_name:<16} {veh.landed_state:<10} "
        f"{'armed' if veh.armed else 'disarmed':<8} alt {veh.rel_alt:6.1f} m  battery {veh.battery:4.0%}"
        + ("" if veh.connected else "  LINK PULLED")
    )


async def run_sim(
    world: World,
    n: int | None,
    *,
    base_port: int = PX4_SITL_BASE,
    agents: bool = False,
    connect: list[str] | None = None,
    agent_config: Path | None = None,
    extra_outputs: list[tuple[str, int]] | None = None,
    radio: bool = False,
    ground_port: int = 7447,
    out: Callable[[str], None] = print,
    log_dir: Path | None = None,
    autopilots: list[str] | None = None,
    params: dict[str, float] | None = None,
) -> None:
    """Run the world's vehicles (and with `agents`, an agent per vehicle, and with
    `radio`, each in its own namespace on the emulated radio) until cancelled. The
    children's output goes to `log_dir/<name>.log` if given, else to ours. `params`
    (`--param`) are set on every vehicle whose autopilot has them, as a ground station
    would set them."""
    specs = world.spawn(n)
    makes = autopilot_of(specs, autopilots)
    params = params or {}
    check_params(params, set(makes.values()))
    vehicles: dict[str, SimVehicle] = {}
    tasks: list[asyncio.Task[None]] = []
    children: list[subprocess.Popen[bytes]] = []
    control_transport: asyncio.BaseTransport | None = None
    loop = asyncio.get_running_loop()
    security = agent_security(agent_config)
    # off the radio, the sensor programs connect where the agents do
    sensor_connect = connect or (read_yaml(agent_config).get("connect") if agent_config else None) or ["tcp/127.0.0.1:7447"]
    field = RadioField(world, [s.id for s in specs], ground_port, security).up() if radio else None
    scratch = scratch_dir()
    try:
        if field is not None:
            for line in field.describe():
                out(line)
        for i, spec in enumerate(specs):
            vehicle = world.vehicle(spec, makes[spec.id])
            # On the radio every drone has its own 127.0.0.1: PX4's first ports serve all.
            port = base_port + (0 if field else i)
            def on_change(_: object, sv_id: str = spec.id) -> None:
                if sv_id in vehicles:
                    out(status_line(vehicles[sv_id]))

            endpoint = MavlinkVehicle(vehicle, i + 1, [("127.0.0.1", port), *(extra_outputs or [])], on_change=on_change,
                                      autopilot=makes[spec.id])
            for name, value in params.items():
                if name in endpoint.params:
                    endpoint.set_param(name, value)
            local = PX4_SITL_LOCAL + (0 if field else i) if base_port == PX4_SITL_BASE else 0
            sock = socket_in_netns(field.net.netns(spec.id)) if field else None
            await endpoint.start(("127.0.0.1", local), sock)
            vehicles[spec.id] = SimVehicle(spec, endpoint, port)
            tasks.append(loop.create_task(endpoint.run(), name=f"sim {spec.id}"))
            for fault in spec.faults:
                loop.call_later(fault.at_s, apply_fault, vehicle, fault.fault, fault.value)
        control_transport = await open_fault_channel(base_port - 1, FaultChannel(
            lambda name: _find(vehicles, name).endpoint.vehicle,
            lambda: {k: status_line(v) for k, v in vehicles.items()},
        ))
        out(f"{len(vehicles)} simulated vehicle(s); fault control on udp 127.0.0.1:{base_port - 1}")
        for v in vehicles.values():
            out(status_line(v))
        if field is not None:
            def where() -> dict[str, Spot3]:
                return {k: spot_of(v.endpoint.vehicle.position()) for k, v in vehicles.items()}

            field.update(where())
            tasks.append(loop.create_task(field.follow(where), name="radio"))
        if agents:
            for v in vehicles.values():
                fc = f"udpin://127.0.0.1:{v.port}"
                # the world's kind, roles and sensor declarations of each drone
                config = drone_agent_config(agent_config, world, v.spec, Path(scratch.name))
                if field is not None:
                    args = field.agent_args(v.spec.id, fc, config, v.spec.kind, list(v.spec.roles or []))
                else:
                    args = agent_command(v.spec.id, fc, connect=connect or [], listen=["tcp/127.0.0.1:0"],
                                         config=config, kind=v.spec.kind, roles=v.spec.roles or ())
                children.append(_child(args, log_dir, v.spec.id))
                out(f"agent {v.spec.id} started (pid {children[-1].pid})")
                for kind in v.spec.sensor_types:  # any type the world reads, beside the agent
                    args = (field.sensor_args(v.spec.id, kind, Path(scratch.name)) if field is not None else
                            sensor_command(world_file(world, Path(scratch.name)), sensor_connect, security,
                                           drone_id=v.spec.id, kind=kind))
                    children.append(_child(args, log_dir, f"{v.spec.id}-{kind}"))
                    out(f"{kind} sensor of {v.spec.id} started (pid {children[-1].pid})")
            for pole in world.field_sensors:  # on their own link to the ground, not the drones' radio
                args = (field.field_sensor_args(pole.id, Path(scratch.name)) if field is not None else
                        sensor_command(world_file(world, Path(scratch.name)), sensor_connect, security, field_id=pole.id))
                children.append(_child(args, log_dir, pole.id))
                out(f"field sensor {pole.id} ({pole.type}) started (pid {children[-1].pid})")
        await asyncio.gather(*tasks)
    finally:
        for child in children:
            child.terminate()
        deadline = time.monotonic() + CHILDREN_STOP_S  # one deadline for all: they stop together
        for child in children:
            try:
                child.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)
        for v in vehicles.values():
            v.endpoint.close()
        if control_transport is not None:
            control_transport.close()
        if field is not None:
            field.close()
        scratch.cleanup()


def _child(args: list[str], log_dir: Path | None, name: str) -> subprocess.Popen[bytes]:
    if log_dir is None:
        return subprocess.Popen(args, preexec_fn=die_with_parent)
    with open(log_dir / f"{name}.log", "ab") as log:  # the child keeps its own descriptor
        return subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                preexec_fn=die_with_parent)
