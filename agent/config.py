"""Agent configuration (SPEC §3, thesis table 4.1 in snake_case), strictly checked.

A YAML file supplies any subset of the keys; command-line flags override it. An
unknown key or a value of the wrong type stops the agent at start with a message
naming the file and the key.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import msgspec
from msgspec import Meta

from dronefleet.agent.link import LostLinkPolicy
from dronefleet.schemas.about import DEFAULT_KIND, DEFAULT_ROLES, Role, SensorDeclaration
from dronefleet.schemas.commands import DEFAULT_RETURN_ALT_M
from dronefleet.schemas.config_loading import Security
from dronefleet.schemas.endpoints import AGENT_PORT, check_endpoints, ip_endpoint, plain_endpoint
from dronefleet.schemas.fence import Geofence


class AgentConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    fc: str = "udp://:14540"
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    # The agent is a router of the mesh (ADR 0003): on-board programs connect to it on
    # 127.0.0.1, neighbouring drones on its radio address.
    listen: list[str] = msgspec.field(default_factory=lambda: [f"tcp/0.0.0.0:{AGENT_PORT}"])
    mesh_interface: str | None = None  # radio interface on which to find neighbours (multicast scouting)
    lost_link: LostLinkPolicy = msgspec.field(default_factory=LostLinkPolicy)
    geofence: Geofence = msgspec.field(default_factory=Geofence)  # SPEC §11: refused here too, uploaded to the autopilot
    security: Security = msgspec.field(default_factory=Security)  # SPEC §9: refuse commands the ground did not sign
    probe_period_ms: Annotated[int, Meta(ge=100, le=60_000)] = 1000  # link probes to the ground and neighbours
    probe_window: Annotated[int, Meta(ge=2, le=600)] = 10  # probes per peer that loss, RTT and jitter cover
    telemetry_rate_ms: Annotated[int, Meta(ge=20, le=60_000)] = 1000
    # While the ground is in doubt (a probe lost, retransmitted or overdue), telemetry at
    # least this often: a sample through a lossy hop or a new way arrives sooner (ADR 0003).
    doubt_telemetry_rate_ms: Annotated[int, Meta(ge=20, le=60_000)] = 250
    acceptance_radius: Annotated[float, Meta(gt=0.0, le=100.0)] = 0.5
    takeoff_altitude: Annotated[float, Meta(gt=0.0, le=1000.0)] = 15.0
    return_altitude: Annotated[float, Meta(ge=0.0, le=1000.0)] = DEFAULT_RETURN_ALT_M
    max_speed: Annotated[float, Meta(gt=0.0, le=50.0)] = 5.0
    namespace: str = ""
    # What the drone is (SPEC §2 About): published on drone/<id>/about for the ground and missions.
    kind: Annotated[str, Meta(min_length=1, max_length=64)] = DEFAULT_KIND
    roles: Annotated[list[Role], Meta(min_length=1)] = msgspec.field(default_factory=lambda: list(DEFAULT_ROLES))
    sensors: list[SensorDeclaration] = msgspec.field(default_factory=list)  # what its readings are held to
    # Where the agent keeps what must outlive it (task bundle records, SPEC §6);
    # `fleet agent` defaults to $XDG_STATE_HOME/fleet/<drone id>. None: memory only.
    state_dir: str | None = None

    def __post_init__(self) -> None:
        check_endpoints(connect=self.connect, listen=self.listen)
        for what, names in (("roles", [str(r) for r in self.roles]), ("sensors", [d.type for d in self.sensors])):
            twice = sorted({n for n in names if names.count(n) > 1})
            if twice:
                raise ValueError(f"{what}: {', '.join(twice)} listed twice")
        if self.mesh_interface is not None and own_endpoint(self.listen) is None:
            # Links through a neighbour reach this agent's router on its own port (agent/neighbours.py).
            raise ValueError("mesh_interface needs a `listen` TCP or TLS endpoint with a fixed port "
                             f"(e.g. tcp/0.0.0.0:{AGENT_PORT}), got {self.listen}")


def own_endpoint(listen: list[str]) -> str | None:
    """Where a bridge in the agent's process reaches its own router (agent/neighbours.py):
    its first TCP or TLS listener on a fixed port, on loopback when it listens on every
    address."""
    for endpoint in listen:
        parsed = ip_endpoint(endpoint)
        if parsed is not None and parsed[0] in ("tcp", "tls") and parsed[2] != 0:
            proto, host, port = parsed
            return f"{proto}/127.0.0.1:{port}" if host in ("0.0.0.0", "::") else plain_endpoint(endpoint)
    return None


def default_state_dir(drone_id: str) -> str:
    """$XDG_STATE_HOME/fleet/<drone id>, i.e. ~/.local/state/fleet/drone01."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return str(Path(base) / "fleet" / drone_id)
