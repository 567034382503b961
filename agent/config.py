"""Agent configuration (SPEC §3, thesis table 4.1 in snake_case), strictly checked.

A YAML file supplies any subset of the keys; command-line flags override it. An
unknown key or a value of the wrong type stops the agent at start with a message
naming the file and the key.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
from msgspec import Meta


class AgentConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    fc: str = "udp://:14540"
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    telemetry_rate_ms: Annotated[int, Meta(ge=20, le=60_000)] = 1000
    acceptance_radius: Annotated[float, Meta(gt=0.0, le=100.0)] = 0.5
    takeoff_altitude: Annotated[float, Meta(gt=0.0, le=1000.0)] = 15.0
    return_altitude: Annotated[float, Meta(ge=0.0, le=1000.0)] = 15.0
    max_speed: Annotated[float, Meta(gt=0.0, le=50.0)] = 5.0
    namespace: str = ""
