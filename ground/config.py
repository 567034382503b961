"""Ground station configuration (SPEC §4, thesis table 4.8 in snake_case), strictly checked.

Every key has a default, so `fleet ground` runs with no file at all. An unknown or
ill-typed key stops the ground at start naming the file and the key (`battery.lowe`
is a typo, not a silently ignored setting).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import yaml
from msgspec import Meta

from dronefleet.schemas.config_loading import MissionSettings, Security
from dronefleet.schemas.endpoints import check_endpoints
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.fence import Geofence

Fraction = Annotated[float, Meta(ge=0.0, le=1.0)]
Millis = Annotated[int, Meta(ge=0, le=86_400_000)]


def default_ground_id() -> str:
    """The host name, as a key can carry it."""
    import re
    import socket

    return re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname()) or "ground"


def default_data_dir() -> str:
    """$XDG_DATA_HOME/fleet, i.e. ~/.local/share/fleet on a usual laptop."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return str(Path(base) / "fleet")


class BatteryLevels(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    critical: Fraction = 0.05  # at or below: the drone is in error and cannot be used
    low: Fraction = 0.15  # at or below: warn the operator


class MapSpot(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    lat: Annotated[float, Meta(ge=-90, le=90)]
    lon: Annotated[float, Meta(ge=-180, le=180)]


class HeatMark(MapSpot, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A known heat source, drawn on the map (the keys of a world file's `heat_sources`)."""

    radius: Annotated[float, Meta(gt=0, le=100_000)]  # m
    temp: float | None = None  # °C at the centre


def missing_placeholders(template: str) -> list[str]:
    """Which of {z}, {x}, {y} a tile URL template lacks."""
    return [p for p in ("{z}", "{x}", "{y}") if p not in template]


class DashboardSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What the web dashboard (`GET /`) draws besides the drones; it only draws these."""

    # Raster map tiles (web mercator): a URL template with {z}, {x}, {y}, or a PMTiles
    # archive (a file, e.g. from `fleet tiles fetch`) that the ground serves itself, for a
    # field with no internet; none: a local metres grid.
    tiles: str | None = None
    attribution: str | None = None  # the map's credit shown on it (an archive's own by default)
    ground_station: MapSpot | None = None  # where the ground stands; none: the first drone's home
    heat_sources: list[HeatMark] = msgspec.field(default_factory=list)

    def __post_init__(self) -> None:
        if self.tiles is None or self.tiles_archive is not None:
            return
        missing = missing_placeholders(self.tiles)
        if missing:
            raise ValueError(f"dashboard.tiles is a URL template with {', '.join(missing)} missing (e.g. "
                             "https://tiles.example/{z}/{x}/{y}.png), or a .pmtiles file (`fleet tiles fetch`)")

    @property
    def tiles_archive(self) -> str | None:
        """The PMTiles file `tiles` names (None: a URL template, or no tiles)."""
        if self.tiles is None or "{" in self.tiles or "://" in self.tiles:
            return None
        return self.tiles


DEFAULT_CEILING_M = 120.0  # geofence.max_alt_m when the configuration gives none (m above home)

Role = Literal["viewer", "operator", "admin"]
ROLE_RANK: dict[str, int] = {"viewer": 0, "operator": 1, "admin": 2}


class ApiToken(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    name: str  # who holds it: named in the event log and the mission record
    role: Role  # viewer: GET only; operator: commands and missions; admin: everything
    token: Annotated[str, Meta(min_length=16)]


class ApiSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """SPEC §9: with any token, every API request needs `Authorization: Bearer …`."""

    tokens: list[ApiToken] = msgspec.field(default_factory=list)
    tokens_file: str | None = None  # a YAML list of {name, role, token}, read at start

    def all_tokens(self) -> list[ApiToken]:
        tokens = list(self.tokens)
        if self.tokens_file is not None:
            path = Path(self.tokens_file).expanduser()
            try:
                loaded = yaml.safe_load(path.read_text()) or []
                if isinstance(loaded, dict):  # also {tokens: [...]}
                    loaded = loaded.get("tokens", [])
                tokens += msgspec.convert(loaded, list[ApiToken])
            except (OSError, yaml.YAMLError, msgspec.ValidationError) as exc:
                raise ConfigError(f"api.tokens_file {path}: {' '.join(str(exc).split())}") from None
        names = [t.token for t in tokens]
        if len(set(names)) != len(names):
            raise ConfigError("api.tokens: the same token is given twice")
        return tokens


class GroundConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/0.0.0.0:7447"])
    # SPEC §14, two grounds on one mesh: who this ground is, how it ranks, whether it may
    # ever command (`observer`: never), and the other grounds' routers it joins.
    ground_id: str = msgspec.field(default_factory=default_ground_id)
    priority: Annotated[int, Meta(ge=-1000, le=1000)] = 0
    role: Literal["ground", "observer"] = "ground"
    connect: list[str] = msgspec.field(default_factory=list)
    http_host: str = "127.0.0.1"  # 0.0.0.0 exposes the command API to the whole network
    http_port: Annotated[int, Meta(ge=0, le=65535)] = 8001
    data_dir: str = msgspec.field(default_factory=default_data_dir)
    plugins_dir: str | None = None  # default: <data_dir>/plugins
    namespace: str = ""
    battery: BatteryLevels = msgspec.field(default_factory=BatteryLevels)
    drone_timeout_ms: Annotated[int, Meta(ge=100, le=3_600_000)] = 5000
    # The registry's bound: telemetry under a new id past it is dropped and counted (one
    # line per 10 s names how many), so made-up ids on an open mesh cannot grow the
    # ground without end (each drone heard holds a record and a route watch).
    max_drones: Annotated[int, Meta(ge=1, le=1_000_000)] = 10_000
    # New drone ids heard before their About (what the drone is) register on their first
    # telemetry from a bucket of 64, refilled at this many per second; the rest are
    # dropped and counted (one line per 10 s) until their agent answers `about`.
    unannounced_per_s: Annotated[float, Meta(ge=0, le=10_000)] = 2.0
    sensor_timeout_ms: dict[str, Millis] = msgspec.field(default_factory=dict)  # per type; 0 = never
    mission: MissionSettings = msgspec.field(default_factory=MissionSettings)
    event_telemetry_ms: Annotated[int, Meta(ge=0, le=60_000)] = 500  # /events: one telemetry per drone per period
    command_timeout_ms: Annotated[int, Meta(ge=100, le=60_000)] = 3000  # waiting for an agent's reply
    link_degraded_below: Fraction = 0.5  # measured link quality under this warns "link degraded"
    # In flight, a health check the autopilot reports failing is a warning this long, an
    # error (the drone in error, its mission failed drone_error) only after: a flag that
    # drops for a moment on a real autopilot is not a failure; what the autopilot does
    # about it (a failsafe, a refused command) ends a mission at once all the same. Not
    # flying, a failing check is an error at once.
    health_error_after_s: Annotated[float, Meta(ge=0, le=3600)] = 5.0
    # SPEC §11: refused at the ground (409 geofence). With no max_alt_m, DEFAULT_CEILING_M:
    # most airspace rules stop at 120 m above ground; a site that may go higher says so.
    geofence: Geofence = msgspec.field(default_factory=Geofence)
    security: Security = msgspec.field(default_factory=Security)  # SPEC §9: sign every command and bundle
    api: ApiSettings = msgspec.field(default_factory=ApiSettings)  # SPEC §9: bearer tokens and roles
    dashboard: DashboardSettings = msgspec.field(default_factory=DashboardSettings)  # SPEC §10: the web page at GET /

    def __post_init__(self) -> None:
        check_endpoints(listen=self.listen, connect=self.connect)
        from dronefleet.schemas.errors import InvalidMessage
        from dronefleet.schemas.grounds import RESERVED
        from dronefleet.schemas.keys import check_id

        try:
            check_id(self.ground_id, "ground_id")
        except InvalidMessage as exc:
            raise ValueError(str(exc)) from None
        if self.ground_id in RESERVED:
            raise ValueError(f"ground_id {self.ground_id!r} is a reserved key word ({', '.join(sorted(RESERVED))})")
        if self.battery.critical > self.battery.low:
            raise ValueError("battery.critical must not exceed battery.low")
        if self.geofence.max_alt_m is None:
            msgspec.structs.force_setattr(self, "geofence",
                                          msgspec.structs.replace(self.geofence, max_alt_m=DEFAULT_CEILING_M))

    @property
    def plugins_path(self) -> Path:
        return Path(self.plugins_dir) if self.plugins_dir else Path(self.data_dir) / "plugins"
