"""Strict loading of YAML configuration files (agent, ground) into msgspec Structs.

A file supplies any subset of the keys; command-line flags override it. An unknown
key or a value of the wrong type stops the program at start with a message naming
the file and the key (nested keys dotted: `battery.low`), and the keys it knows.
"""

from __future__ import annotations

import re
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from dronefleet.schemas.errors import ConfigError

_UNKNOWN = re.compile(r"unknown field `([^`]*)`(?: - at `\$\.?([^`]*)`)?")


class MissionSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    return_on_critical_battery: bool = True  # a mission drone at critical battery is sent home
    end_action: Literal["hold", "return"] = "hold"  # what flying drones do when their mission ends
    link_grace_s: Annotated[float, Meta(ge=0, le=3600)] = 30.0  # how long a mission waits for a drone whose link is lost
    clear_wait_s: Annotated[float, Meta(ge=0, le=3600)] = 120.0  # move(..., wait_clear=True): longest wait for a spot
    # Each mission's script runs in a process of its own on the ground (SPEC §9, ADR 0009): what it
    # may allocate beyond the runtime's own memory, and the CPU time it may use in all.
    max_memory_mb: Annotated[int, Meta(ge=16, le=1_048_576)] = 1024
    max_cpu_s: Annotated[float, Meta(ge=1, le=1_000_000)] = 3600.0
    # Before a submitted mission flies, the ground flies it in fast time against the live
    # fleet (ground/preflight.py); one that fails is refused (422). Simulated seconds it may run.
    preflight: bool = True
    preflight_max_s: Annotated[float, Meta(ge=10, le=86_400)] = 1800.0
    # Wall seconds a preflight may take on the ground's machine (its child process also has
    # the script's memory limit): a script still computing at its own line then is refused,
    # one whose simulation was still flying passes, judged as far as it got.
    preflight_wall_s: Annotated[float, Meta(ge=1, le=600)] = 5.0
    # Preflights (and the planner's simulations) that run side by side; one more is 503.
    preflight_concurrency: Annotated[int, Meta(ge=1, le=64)] = 2
    # What a predicted flight drains from a battery, a fraction per second in the air (the
    # preflight's and the planner's; 0.0008: a full pack lasts about 20 minutes of flight).
    flight_drain_per_s: Annotated[float, Meta(ge=0, le=0.1)] = 0.0008


class Security(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """SPEC §9, for the ground and the agent. With `pki_dir` (`fleet pki init/issue`) the
    ground signs every command and bundle with `<pki_dir>/signing.key`, and an agent
    refuses any that `<pki_dir>/signing.pub` (or `ground_key`) does not verify."""

    pki_dir: str | None = None
    tls: bool = False  # every Zenoh link mutual TLS with the certificate <pki_dir>/<name>.pem; endpoints tls/…
    name: str | None = None  # this node's certificate in pki_dir (default: the drone id, or "ground")
    ground_key: str | None = None  # agent: the ground's public key, if not <pki_dir>/signing.pub
    window_s: Annotated[float, Meta(gt=0, le=3600)] = 30.0  # agent: how old (or early) a signature may be
    # A router dialling a neighbour (a drone: the ground, relays) checks that the address
    # it dialled is in the neighbour's certificate. Off by default: routers know a node by
    # its certificate's CN, which their access rules check (ADR 0010), and the addresses
    # they learn by gossip are every interface of the neighbour.
    verify_names: bool = False

    def __post_init__(self) -> None:
        if self.tls and self.pki_dir is None:
            raise ValueError("security.tls needs security.pki_dir (the directory of `fleet pki init`)")



def load_config(kind: type[msgspec.Struct], path: Path | None, overrides: dict[str, Any]) -> Any:
    """Read `path` (YAML) into `kind`, apply non-None overrides, validate strictly."""
    where = str(path) if path else "configuration"
    data: dict[str, Any] = read_yaml(path) if path is not None else {}
    data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return msgspec.convert(data, kind)
    except msgspec.ValidationError as exc:
        text = str(exc)
        unknown = _UNKNOWN.search(text)
        if unknown:
            key, parent = unknown.group(1), unknown.group(2) or ""
            known = ", ".join(_fields_at(kind, parent))
            dotted = f"{parent}.{key}" if parent else key
            raise ConfigError(f"{where}: unknown key {dotted!r} (known keys{' of ' + parent if parent else ''}: {known})") from None
        raise ConfigError(f"{where}: {text.replace('$.', '')}") from None


def read_yaml(path: Path) -> dict[str, Any]:
    """A YAML file holding a mapping (or nothing); ConfigError on one line otherwise."""
    import yaml  # here, not above: an agent started without a file never loads it (agent/footprint.py)

    try:
        loaded = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise ConfigError(f"{path}: not valid YAML{where}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    if loaded is not None and not isinstance(loaded, dict):
        raise ConfigError(f"{path}: expected a mapping of keys to values, got {type(loaded).__name__}")
    return dict(loaded or {})


def _fields_at(kind: type[msgspec.Struct], dotted: str) -> tuple[str, ...]:
    """Field names of the Struct found by following `dotted` from `kind` (`drones[0]`
    steps into the list's element type)."""
    for part in filter(None, dotted.split(".")):
        name, indexed = _INDEX.sub("", part), _INDEX.search(part) is not None
        match = next((f for f in msgspec.structs.fields(kind) if f.encode_name == name), None)
        found = _struct_in(None if match is None else match.type, indexed)
        if found is None:
            return ()
        kind = found
    return kind.__struct_fields__


def _struct_in(hint: Any, indexed: bool) -> type[msgspec.Struct] | None:
    """The Struct a field holds: itself, the element of a list (when indexed), or the
    Struct member of an optional."""
    if indexed and typing.get_origin(hint) is list:
        (hint,) = typing.get_args(hint)
    for candidate in (hint, *typing.get_args(hint)):
        if isinstance(candidate, type) and issubclass(candidate, msgspec.Struct):
            return candidate
    return None


_INDEX = re.compile(r"\[\d+\]$")


def writable_dir(path: Path, option: str) -> Path:
    """Create `path` if needed and prove a file can be written there, before any long
    work whose results would go there; ConfigError names the option otherwise."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".fleet-write-probe"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot write there: {exc.strerror or exc}") from None
    return path
