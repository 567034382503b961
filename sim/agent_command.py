"""The command lines of the `fleet` processes the simulators start (`fleet sim --agents`,
the emulated radio, `fleet demo`): one place that spells `fleet agent`'s options."""

from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from dronefleet.schemas.config_loading import Security
    from dronefleet.sim.world import DroneSpec, World


def fleet_command(*args: str) -> list[str]:
    """`fleet ARGS…` run by this interpreter (the package, not a console script on PATH)."""
    return [sys.executable, "-m", "dronefleet", *args]


def agent_command(drone_id: str, fc: str, *, connect: Iterable[str] = (), listen: Iterable[str] = (),
                  mesh_interface: str | None = None, telemetry_rate_ms: int | None = None,
                  state_dir: Path | None = None, config: Path | None = None, kind: str | None = None,
                  roles: Iterable[str] = ()) -> list[str]:
    """`fleet agent --id ID --fc FC …` (SPEC §3)."""
    args = ["agent", "--id", drone_id, "--fc", fc]
    if kind is not None:
        args += ["--kind", kind]
    for role in roles:
        args += ["--role", role]
    for endpoint in connect:
        args += ["--connect", endpoint]
    for endpoint in listen:
        args += ["--listen", endpoint]
    if mesh_interface is not None:
        args += ["--mesh-interface", mesh_interface]
    if telemetry_rate_ms is not None:
        args += ["--telemetry-rate-ms", str(telemetry_rate_ms)]
    if state_dir is not None:
        args += ["--state-dir", str(state_dir)]
    if config is not None:
        args += ["--config", str(config)]
    return fleet_command(*args)


def sensor_command(world_file: Path, connect: Iterable[str], security: Security | None = None, *,
                   drone_id: str | None = None, kind: str | None = None, field_id: str | None = None) -> list[str]:
    """`fleet sensor simulate --world W` for a drone's sensor `kind` or the field sensor
    `field_id`; on a secured mesh showing the drone's certificate (or the field sensor's own)."""
    args = ["sensor", "simulate", "--world", str(world_file)]
    if field_id is not None:
        args += ["--field", field_id]
    else:
        assert drone_id is not None and kind is not None
        args += ["--drone", drone_id, "--type", kind]
    for endpoint in connect:
        args += ["--connect", endpoint]
    if security is not None and security.tls:
        assert security.pki_dir is not None
        args += ["--pki-dir", security.pki_dir, "--name", field_id or security.name or str(drone_id)]
    return fleet_command(*args)


def world_file(world: World, out_dir: Path) -> Path:
    """The world as a file for the sensor programs (`fleet sensor simulate --world`), written once."""
    import msgspec
    import yaml

    path = out_dir / "world.yml"
    if not path.exists():
        out_dir.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(msgspec.to_builtins(world)))
    return path


def drone_agent_config(base: Path | None, world: World, spec: DroneSpec, out_dir: Path) -> Path | None:
    """One world drone's agent config: `base`'s keys and the drone's sensor declarations
    (SPEC §2 About, `World.declarations`), written to out_dir/<id>-agent.yml; `base`
    itself when the drone carries no sensor (or the base config declares its own)."""
    import msgspec
    import yaml

    from dronefleet.schemas.config_loading import read_yaml

    declared = world.declarations(spec)
    data = read_yaml(base) if base is not None else {}
    if not declared or "sensors" in data:
        return base
    data["sensors"] = msgspec.to_builtins(declared)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{spec.id}-agent.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
