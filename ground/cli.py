"""`fleet drone …` and `fleet logs`: the operator's command line over the ground's HTTP API.

Every command takes `--url` (default http://127.0.0.1:8001, or $FLEET_URL). Errors
print the API's own message ("drone is under manual control") and exit 1; a ground
that cannot be reached says so and names the URL.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NoReturn, get_args

import click

if TYPE_CHECKING:
    import httpx

from dronefleet.ground.describe import Level
from dronefleet.schemas.fleet import DRONE_STATES

DEFAULT_URL = "http://127.0.0.1:8001"
FOLLOW_PERIOD_S = 0.5
url_option = click.option(
    "--url", envvar="FLEET_URL", default=DEFAULT_URL, show_default=True, help="The ground's HTTP API (env FLEET_URL)."
)


def _fail(message: str, code: int = 1) -> NoReturn:
    click.echo(f"fleet: {message}", err=True)
    sys.exit(code)


def auth_headers() -> dict[str, str]:
    """`Authorization` from $FLEET_TOKEN, for a ground with api.tokens (SPEC §9)."""
    token = os.environ.get("FLEET_TOKEN")
    return {"Authorization": f"Bearer {token}"} if token else {}


def _request(method: str, url: str, path: str, **kwargs: Any) -> httpx.Response:
    import httpx  # the ground extra: a drone's `fleet agent` never loads it

    kwargs["headers"] = {**kwargs.get("headers", {}), **auth_headers()}
    try:
        response = httpx.request(method, url.rstrip("/") + path, **{"timeout": 10.0, **kwargs})
    except httpx.TransportError as exc:
        _fail(f"cannot reach the ground at {url}: {exc} (is `fleet ground` running? see --url)")
    if response.status_code >= 400:
        try:
            message = response.json().get("error") or response.text
        except (ValueError, AttributeError):
            message = response.text
        _fail(f"{response.status_code}: {message}")
    return response


@click.group()
def drone() -> None:
    """List, inspect and command drones through the ground."""


def _cell(value: Any) -> str:
    return "-" if value in (None, "", []) else str(value)


def drone_table(views: list[dict[str, Any]]) -> list[str]:
    header = ("DRONE", "STATE", "BATTERY", "MODE", "ALT", "COMMAND", "MISSION", "ALERTS")
    rows = [header]
    for view in views:
        info, telem = view.get("info") or {}, view.get("telem") or {}
        battery = (telem.get("battery") or {}).get("remaining_percent")
        position = telem.get("position") or {}
        current = info.get("current_command") or {}
        rows.append((
            _cell(info.get("drone_id") or telem.get("drone_id")), _cell(info.get("state")),
            _cell(f"{battery:.0%}" if battery is not None else None), _cell(telem.get("flight_mode")),
            _cell(f"{position['rel_alt']:.1f} m" if "rel_alt" in position else None),
            _cell(current.get("description")), _cell(info.get("mission")),
            _cell("; ".join((info.get("errors") or []) + (info.get("warns") or []))),
        ))
    return aligned(rows)


def aligned(rows: Sequence[tuple[str, ...]]) -> list[str]:
    """Rows of cells as lines with every column padded to its widest cell."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in rows]


@drone.command("list")
@url_option
@click.option("--state", type=click.Choice(DRONE_STATES), help="Only drones in this state.")
@click.option("--sensor", "sensors", multiple=True, help="Only drones carrying this sensor type (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print the API's JSON instead of a table.")
def list_drones(url: str, state: str | None, sensors: tuple[str, ...], as_json: bool) -> None:
    """A table of the drones the ground knows."""
    params: list[tuple[str, str]] = [("sensors", s) for s in sensors] + ([("state", state)] if state else [])
    views = _request("GET", url, "/drone", params=params).json()
    if as_json:
        click.echo(json.dumps(views, indent=2))
    elif not views:
        click.echo("no drones" + (" match" if params else " registered yet"))
    else:
        for line in drone_table(views):
            click.echo(line)


@drone.command("wait")
@url_option
@click.argument("drone_ids", metavar="DRONE_ID...", nargs=-1, required=True)
@click.option("--state", type=click.Choice(DRONE_STATES), default="ready", show_default=True,
              help="The state every drone must reach.")
@click.option("--timeout", "timeout_s", type=click.FloatRange(min=0.1, max=86_400), default=60.0, show_default=True,
              help="Seconds to wait at most.")
def wait_drones(url: str, drone_ids: tuple[str, ...], state: str, timeout_s: float) -> None:
    """Wait until every DRONE_ID is in STATE at the ground (a ground still starting is
    waited for too); prints each as it gets there, exits 1 at the timeout naming the rest."""
    import httpx

    deadline = time.monotonic() + timeout_s
    left = dict.fromkeys(drone_ids, "not registered")
    while True:
        try:
            views = httpx.get(url.rstrip("/") + "/drone", headers=auth_headers(), timeout=5.0).json()
            seen = {v["info"]["drone_id"]: v["info"]["state"] for v in views}
        except (httpx.TransportError, ValueError):
            seen = {}  # the ground is not answering yet
        for drone_id in list(left):
            left[drone_id] = seen.get(drone_id, left[drone_id])
            if left[drone_id] == state:
                click.echo(f"{drone_id} {state}")
                del left[drone_id]
        if not left:
            return
        if time.monotonic() >= deadline:
            _fail(f"after {timeout_s:g} s not {state}: " + ", ".join(f"{d} ({s})" for d, s in left.items()))
        time.sleep(0.5)


@drone.command("show")
@url_option
@click.argument("drone_id")
def show_drone(url: str, drone_id: str) -> None:
    """Everything the ground knows of one drone (JSON)."""
    click.echo(json.dumps(_request("GET", url, f"/drone/{drone_id}").json(), indent=2))


def parse_fields(pairs: tuple[str, ...]) -> dict[str, Any]:
    """`alt=10 yaw=null mode=action` → {"alt": 10, "yaw": None, "mode": "action"}."""
    fields: dict[str, Any] = {}
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"{pair!r} is not key=value", param_hint="FIELDS")
        try:
            fields[key] = json.loads(raw)
        except ValueError:
            fields[key] = raw
    return fields


@drone.command("cmd")
@url_option
@click.argument("drone_id")
@click.argument("cmd")
@click.argument("fields", nargs=-1)
def command(url: str, drone_id: str, cmd: str, fields: tuple[str, ...]) -> None:
    """Send CMD to DRONE_ID with key=value FIELDS, e.g. `fleet drone cmd drone01 takeoff alt=10`.

    Exits 0 when the agent accepted it (completion shows in `fleet logs`), 1 otherwise.
    """
    body = {"cmd": cmd, **parse_fields(fields)}
    reply = _request("POST", url, f"/drone/{drone_id}/cmd", json=body).json()
    click.echo(f"accepted {cmd} for {drone_id} (command {reply['command_id']})")


@click.command()
@url_option
@click.option("--drone", "drones", multiple=True, help="Only this drone (repeatable).")
@click.option("--level", "levels", multiple=True, type=click.Choice(get_args(Level)), help="Only this level (repeatable).")
@click.option("--follow", "-f", is_flag=True, help="Keep printing new lines until Ctrl-C.")
def logs(url: str, drones: tuple[str, ...], levels: tuple[str, ...], follow: bool) -> None:
    """The ground's event log, oldest first."""
    params: list[tuple[str, str | int]] = [*(("drone_id", d) for d in drones), *(("loglevel", lv) for lv in levels)]
    cursor = 0
    try:
        while True:
            response = _request("GET", url, "/drone/logs", params=[*params, ("after", cursor)])
            click.echo(response.text, nl=False)
            cursor = int(response.headers.get("Fleet-Log-Cursor", cursor))
            if not follow:
                return
            time.sleep(FOLLOW_PERIOD_S)
    except KeyboardInterrupt:
        return
