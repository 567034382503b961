"""The `fleet` command line's toolkit, shared by its command modules (dronefleet/cli.py,
mission_cli, recording_cli, pki): option types, the error boundary, running a
coroutine until Ctrl-C, log levels, PKI options."""

from __future__ import annotations

import asyncio
import faulthandler
import signal
import sys
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import click

from dronefleet.bus.loop_watch import LoopWatch
from dronefleet.schemas.endpoints import check_endpoint, split_host_port
from dronefleet.schemas.errors import ConfigError, FleetError

# Long-running services print what they do at INFO; clients only warn unless asked.
SERVICES = frozenset({"agent", "ground", "sim", "demo", "sensor"})
# The extra (pyproject.toml) that brings each optional library.
EXTRA_OF = {"zenoh": "agent", "mavsdk": "agent", "litestar": "ground", "uvicorn": "ground", "httpx": "ground",
            "greenlet": "ground", "mcap": "ground", "pmtiles": "ground", "mercantile": "ground", "pymavlink": "sim",
            "matplotlib": "plots", "numpy": "plots"}
LIBRARIES = ("zenoh", "httpx", "httpcore", "matplotlib", "asyncio", "mavsdk", "grpc", "uvicorn")


PKI_DIR_HELP = ("PKI directory (`fleet pki init/issue`): sets security.pki_dir and, unless the config sets "
                "security.tls, turns mutual TLS on (SPEC §9).")


def security_with_pki(config_path: Path | None, pki_dir: str | None) -> dict[str, Any] | None:
    """The config's `security` with `--pki-dir` applied (None: no flag, the config's own
    stands). The flag implies `tls: true` unless the config says otherwise."""
    if pki_dir is None:
        return None
    from dronefleet.schemas.config_loading import read_yaml

    security = dict((read_yaml(config_path) if config_path is not None else {}).get("security") or {})
    security["pki_dir"] = pki_dir
    security.setdefault("tls", True)
    return security


def secured_client(pki_dir: Path | None, name: str, connect: list[str]) -> dict[str, Any]:
    """Zenoh settings of a client (`fleet sub`, `record`, `replay`) on a secured mesh."""
    from dronefleet.bus.mesh_security import mesh_security
    from dronefleet.schemas.config_loading import Security

    if pki_dir is None:
        return {}
    return mesh_security(Security(pki_dir=str(pki_dir), tls=True, name=name), name, connect, router=False)


pki_options = [
    click.option("--pki-dir", type=click.Path(file_okay=False, exists=True, path_type=Path),
                 help="On a secured mesh (SPEC §9): the directory with ca.pem and NAME.pem/NAME.key; endpoints tls/…"),
    click.option("--name", "cert_name", default="operator", show_default=True, help="The certificate to show, with --pki-dir."),
]


def with_pki(f: Any) -> Any:
    for option in reversed(pki_options):
        f = option(f)
    return f


def run_async(main: Coroutine[Any, Any, Any], stop_grace_s: float | None = None) -> Any:
    """Run `main` until done, Ctrl-C or SIGTERM; both cancel it so `finally` blocks run.
    A loop blocked for over a second is logged with where it is (bus/loop_watch.py).

    `stop_grace_s`: a process told to stop by SIGTERM that is still there this long
    after prints every thread's stack and exits 1 (faulthandler's watchdog, a C thread:
    it fires even if a thread holds the GIL or a native call never returns). A
    supervisor's stop then ends the process, and says where its clean-up hung."""
    context = click.get_current_context(silent=True)
    name = context.command_path if context is not None else "fleet"

    async def wrapper() -> Any:
        task = asyncio.current_task()
        assert task is not None

        def stop() -> None:
            if stop_grace_s is not None:
                faulthandler.dump_traceback_later(stop_grace_s, exit=True)
            task.cancel()

        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop)
        watch = LoopWatch(name)
        try:
            return await main
        except asyncio.CancelledError:
            return None
        finally:
            watch.close()

    try:
        return asyncio.run(wrapper())
    except KeyboardInterrupt:
        return None


def fail(message: str, code: int = 1) -> None:
    click.echo(f"fleet: {message}", err=True)
    sys.exit(code)


class FleetGroup(click.Group):
    """Turns the package's deliberate errors into one line and an exit code."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except FleetError as exc:
            click.echo(f"fleet: {exc}", err=True)
            ctx.exit(exc.exit_code)
        except ModuleNotFoundError as exc:
            library = (exc.name or "").partition(".")[0]
            if library not in EXTRA_OF:
                raise
            extra = EXTRA_OF[library]
            command = ctx.invoked_subcommand or "this command"
            click.echo(f"fleet: `fleet {command}` needs {library}, which comes with the {extra!r} extra: "
                       f"pip install 'dronefleet[{extra}]'", err=True)
            ctx.exit(1)
        except OSError as exc:  # a file or socket the user named
            where = f": {exc.filename}" if exc.filename else ""
            click.echo(f"fleet: {exc.strerror or exc}{where}", err=True)
            ctx.exit(1)


class EndpointType(click.ParamType):
    name = "ENDPOINT"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        try:
            return check_endpoint(str(value))
        except ConfigError as exc:
            self.fail(str(exc), param, ctx)


class HostPortType(click.ParamType):
    name = "HOST:PORT"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> tuple[str, int]:
        if isinstance(value, tuple):
            return value
        try:
            return split_host_port(str(value))
        except ConfigError as exc:
            self.fail(str(exc), param, ctx)


class NameValueType(click.ParamType):
    """NAME=VALUE with a number for VALUE (an autopilot parameter)."""

    name = "NAME=VALUE"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> tuple[str, float]:
        if isinstance(value, tuple):
            return value
        name, eq, number = str(value).partition("=")
        try:
            if not eq or not name.strip():
                raise ValueError
            return name.strip().upper(), float(number)
        except ValueError:
            self.fail(f"{value!r} is not NAME=VALUE with a number (e.g. MPC_LAND_SPEED=1.2)", param, ctx)


NAME_VALUE = NameValueType()


def checked_id(value: str, where: str) -> str:
    from dronefleet.schemas.errors import InvalidMessage
    from dronefleet.schemas.keys import check_id

    try:
        return check_id(value)
    except InvalidMessage as exc:
        raise ConfigError(f"{where}: {exc}") from None


def drone_id_option(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    try:
        return None if value is None else checked_id(value, "drone id")
    except ConfigError as exc:
        raise click.BadParameter(str(exc)) from None


ENDPOINT = EndpointType()
HOST_PORT = HostPortType()


def log_levels(command: str | None, verbose: int) -> tuple[str, str]:
    """(Fleet's level, the libraries' level) for a command and a -v count."""
    steps = ["WARNING", "INFO", "DEBUG"]
    base = 1 if command in SERVICES else 0
    fleet = steps[min(base + verbose, 2)]
    return fleet, "DEBUG" if verbose >= 2 else "WARNING"
