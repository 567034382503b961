"""Agent configuration (SPEC §3, thesis table 4.1 in snake_case), strictly checked.

A YAML file supplies any subset of the keys; command-line flags override it. An
unknown key or a value of the wrong type stops the agent at start with a message
naming the file and the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import msgspec
import yaml
from msgspec import Meta

from schemas.errors import ConfigError


class AgentConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    fc: str = "udp://:14540"
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    telemetry_rate_ms: Annotated[int, Meta(ge=20, le=60_000)] = 1000
    acceptance_radius: Annotated[float, Meta(gt=0.0, le=100.0)] = 0.5
    takeoff_altitude: Annotated[float, Meta(gt=0.0, le=1000.0)] = 15.0
    return_altitude: Annotated[float, Meta(ge=0.0, le=1000.0)] = 15.0
    max_speed: Annotated[float, Meta(gt=0.0, le=50.0)] = 5.0
    namespace: str = ""


def load_config(kind: type[msgspec.Struct], path: Path | None, overrides: dict[str, Any]) -> Any:
    """Read `path` (YAML) into `kind`, apply non-None overrides, validate strictly."""
    where = str(path) if path else "configuration"
    data: dict[str, Any] = {}
    if path is not None:
        try:
            loaded = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not valid YAML: {exc}") from None
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: expected a mapping of keys to values, got {type(loaded).__name__}")
        data = dict(loaded or {})
    data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return msgspec.convert(data, kind)
    except msgspec.ValidationError as exc:
        text = str(exc)
        if "unknown field" in text:
            key = text.split("`")[1]
            known = ", ".join(kind.__struct_fields__)
            raise ConfigError(f"{where}: unknown key {key!r} (known keys: {known})") from None
        raise ConfigError(f"{where}: {text.replace('$.', '')}") from None
