"""Ground station configuration (SPEC §4, thesis table 4.8 in snake_case), strictly checked.

Every key has a default, so `fleet ground` runs with no file at all. An unknown or
ill-typed key stops the ground at start naming the file and the key (`battery.lowe`
is a typo, not a silently ignored setting).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import msgspec
from msgspec import Meta

from schemas.config import MissionSettings
from schemas.endpoints import check_endpoints
from schemas.fence import Geofence

Fraction = Annotated[float, Meta(ge=0.0, le=1.0)]
Millis = Annotated[int, Meta(ge=0, le=86_400_000)]


def default_data_dir() -> str:
    """$XDG_DATA_HOME/fleet, i.e. ~/.local/share/fleet on a usual laptop."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return str(Path(base) / "fleet")


class BatteryLevels(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    critical: Fraction = 0.05  # at or below: the drone is in error and cannot be used
    low: Fraction = 0.15  # at or below: warn the operator


class GroundConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/0.0.0.0:7447"])
    http_host: str = "127.0.0.1"  # 0.0.0.0 exposes the command API to the whole network
    http_port: Annotated[int, Meta(ge=0, le=65535)] = 8001
    data_dir: str = msgspec.field(default_factory=default_data_dir)
    plugins_dir: str | None = None  # default: <data_dir>/plugins
    namespace: str = ""
    battery: BatteryLevels = msgspec.field(default_factory=BatteryLevels)
    drone_timeout_ms: Annotated[int, Meta(ge=100, le=3_600_000)] = 5000
    sensor_timeout_ms: dict[str, Millis] = msgspec.field(default_factory=dict)  # per type; 0 = never
    mission: MissionSettings = msgspec.field(default_factory=MissionSettings)
    event_telemetry_ms: Annotated[int, Meta(ge=0, le=60_000)] = 500  # /events: one telemetry per drone per period
    command_timeout_ms: Annotated[int, Meta(ge=100, le=60_000)] = 3000  # waiting for an agent's reply
    link_degraded_below: Fraction = 0.5  # measured link quality under this warns "link degraded"
    geofence: Geofence = msgspec.field(default_factory=Geofence)  # SPEC §11: refused at the ground (409 geofence)

    def __post_init__(self) -> None:
        check_endpoints(listen=self.listen)
        if self.battery.critical > self.battery.low:
            raise ValueError("battery.critical must not exceed battery.low")

    @property
    def plugins_path(self) -> Path:
        return Path(self.plugins_dir) if self.plugins_dir else Path(self.data_dir) / "plugins"
