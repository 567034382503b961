"""`fleet mission submit|list|show|cancel|check|simulate`.

`submit`, `list`, `show` and `cancel` talk to a ground over HTTP (`--url`/FLEET_URL);
`check` and `simulate` run locally. `submit --watch` and `simulate` exit with the
mission's outcome: 0 finished, 1 failed, 3 cancelled (2 stays click's usage error).
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import click
import msgspec

from dronefleet.ground.cli import _cell, _fail, _request, aligned, auth_headers, url_option

EXIT_CODES = {"finished": 0, "failed": 1, "cancelled": 3}
ENDED = frozenset(EXIT_CODES)
PREFLIGHT_WAIT_S = 240.0  # the ground stops a preflight after 180 s (ground/planning.py) and may queue it behind another


@click.group()
def mission() -> None:
    """Submit, follow, cancel, check and simulate missions."""


def _read_script(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        _fail(f"{path}: cannot read: {exc}")


def _stamp(ms: int | None) -> str:
    if ms is None:
        return "-"
    return time.strftime("%H:%M:%S", time.localtime(ms / 1000)) + f".{ms % 1000:03d}"


def outcome(record: dict[str, Any]) -> str:
    text = f"mission {record['mission_id']} {record['status']}"
    if record.get("cause"):
        text += f": {record['cause']}"
    if record.get("message") and record.get("message") not in (record.get("cause"), "success"):
        text += f" - {record['message']}"
    return text


@mission.command()
@url_option
@click.argument("script", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--name", default="", help="A label for `fleet mission list` (default: the file name).")
@click.option("--watch", "-w", is_flag=True, help="Print the mission's log until it ends; exit with its outcome.")
@click.option("--no-preflight", is_flag=True,
              help="Fly it without its preflight (fast time against the live fleet first); the ground logs that you did.")
def submit(url: str, script: Path, name: str, watch: bool, no_preflight: bool) -> None:
    """Send SCRIPT to the ground; prints the mission id.

    The ground first flies it in fast time against the fleet as it is now (its
    preflight): a mission that would fail is not flown, and this exits 1 naming the
    line, the simulated time and the cause."""
    source = _read_script(script)
    params = {"name": name or script.name, "preflight": "false" if no_preflight else "true"}
    if not no_preflight:
        click.echo("preflight: flying it in fast time against the live fleet …", err=True)
    if not watch:
        created = _submit(url, source, params)
        click.echo(created["mission_id"])
        return
    import httpx  # the ground extra

    # Listen first, then submit: no line of the new mission can slip by.
    try:
        with httpx.stream(
            "GET", url.rstrip("/") + "/events", params=[("types", "mission"), ("types", "mission_log")],
            timeout=httpx.Timeout(10.0, read=None), headers=auth_headers(),
        ) as stream:
            created = _submit(url, source, params)
            mission_id = created["mission_id"]
            click.echo(f"mission {mission_id} submitted")
            for kind, data in _sse(stream.iter_lines()):
                if data.get("mission_id") != mission_id:
                    continue
                if kind == "mission_log":
                    click.echo(f"{_stamp(data['timestamp'])} {data['level'].upper():5} {data['message']}")
                elif kind == "mission" and data.get("status") in ENDED and data.get("end") is not None:
                    click.echo(outcome(data))
                    raise SystemExit(EXIT_CODES[data["status"]])
    except httpx.TransportError as exc:
        _fail(f"lost the ground at {url}: {exc}")
    except KeyboardInterrupt:
        click.echo(f"stopped watching; the mission goes on (cancel: fleet mission cancel {mission_id})", err=True)
        raise SystemExit(130) from None
    _fail("the ground closed the event stream before the mission ended")


def _submit(url: str, source: str, params: dict[str, str]) -> dict[str, Any]:
    created: dict[str, Any] = _request("POST", url, "/mission", content=source.encode(), params=params,
                                       timeout=PREFLIGHT_WAIT_S).json()
    if created.get("preflight"):
        click.echo(preflight_summary(created["preflight"]), err=True)
    return created


def preflight_summary(reported: dict[str, Any]) -> str:
    """The ground's one line for a submission's preflight, from the API's JSON."""
    import msgspec

    from dronefleet.ground.preflight import Preflight

    return msgspec.convert(reported, Preflight).summary()


def _sse(lines: Any) -> Any:
    kind, data = "message", list[str]()
    for line in lines:
        if not line:
            if data:
                yield kind, json.loads("\n".join(data))
            kind, data = "message", []
        elif line.startswith("event:"):
            kind = line[6:].strip()
        elif line.startswith("data:"):
            data.append(line[5:].strip())


@mission.command("list")
@url_option
@click.option("--json", "as_json", is_flag=True, help="Print the API's JSON.")
def list_missions(url: str, as_json: bool) -> None:
    """Every mission the ground knows, oldest first."""
    records = _request("GET", url, "/mission").json()
    if as_json:
        click.echo(json.dumps(records, indent=2))
        return
    rows = [("MISSION", "NAME", "STATUS", "CAUSE", "START", "END", "DRONES")]
    for r in records:
        rows.append((r["mission_id"], _cell(r.get("name")), r["status"], _cell(r.get("cause")),
                     _stamp(r.get("start")), _stamp(r.get("end")), _cell(",".join(r.get("used_drones") or []))))
    for line in aligned(rows):
        click.echo(line)


@mission.command()
@url_option
@click.argument("mission_id")
@click.option("--json", "as_json", is_flag=True, help="Print the API's JSON.")
def show(url: str, mission_id: str, as_json: bool) -> None:
    """One mission's record and log."""
    view = _request("GET", url, f"/mission/{mission_id}").json()
    if as_json:
        click.echo(json.dumps(view, indent=2))
        return
    click.echo(outcome(view) if view["status"] in ENDED else f"mission {mission_id} {view['status']}")
    click.echo(f"  start {_stamp(view.get('start'))}  end {_stamp(view.get('end'))}")
    click.echo(f"  active {', '.join(view['active_drones']) or '-'}  used {', '.join(view['used_drones']) or '-'}")
    for line in view.get("log", []):
        click.echo(f"{_stamp(line['timestamp'])} {line['level'].upper():5} {line['message']}")


@mission.command()
@url_option
@click.argument("mission_id")
def cancel(url: str, mission_id: str) -> None:
    """Cancel a running mission (cause user); its drones hold and are released."""
    record = _request("DELETE", url, f"/mission/{mission_id}").json()
    click.echo(f"mission {record['mission_id']} cancelling")


@mission.command("import")
@click.argument("plan", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--drone", "drone_id", help="Fly it on this drone (default: any free drone).")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), help="Write the script here (default: stdout).")
@click.option("--fence-out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the plan's inclusion polygon here, in the ground's `geofence:` form.")
def import_(plan: Path, drone_id: str | None, out: Path | None, fence_out: Path | None) -> None:
    """Turn a QGroundControl PLAN (.plan, mission version 2) into a mission script
    (SPEC §13). What cannot be carried over is named on stderr with its item number."""
    import yaml

    from dronefleet.mission.script.qgc_plan import import_plan
    from dronefleet.schemas.keys import check_id

    if drone_id is not None:
        check_id(drone_id)
    imported = import_plan(_read_script(plan), drone_id, source=plan.name)
    for line in imported.left_out:
        click.echo(f"{plan}: {line}", err=True)
    if out is None:
        click.echo(imported.script, nl=False)
    else:
        out.write_text(imported.script, encoding="utf-8")
        click.echo(f"{out}: {imported.script.count(chr(10))} lines", err=True)
    if fence_out is not None:
        if imported.geofence is None:
            click.echo(f"{plan}: no inclusion polygon: {fence_out} not written", err=True)
        else:
            fence_out.write_text(yaml.safe_dump({"geofence": imported.geofence}, default_flow_style=None), encoding="utf-8")


@mission.command()
@click.argument("script", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--plugins-dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Also know the verbs of the plugin scripts in this directory (besides the bundled ones).")
def check(script: Path, plugins_dir: Path | None) -> None:
    """Check SCRIPT without running it: syntax, sandbox rules, names defined nowhere
    (with the nearest known one), verbs called with arguments they do not take, a
    drone's attributes and units where literals show them. What only flying shows is
    the preflight's (`fleet mission submit`)."""
    from dronefleet.mission.script.checks import check_script
    from dronefleet.mission.script.plugins import PluginLibrary

    problems = check_script(_read_script(script), str(script), PluginLibrary.default(plugins_dir).verbs())
    for p in problems:
        click.echo(f"{script}:{p.line}:{p.column}: {p.kind} error: {p.message}", err=True)
    if problems:
        raise SystemExit(1)
    click.echo(f"{script}: ok")


@mission.command()
@click.argument("script", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("inputs", nargs=-1, metavar="[key=value…]")
@click.option("--world", type=click.Path(exists=True, dir_okay=False, path_type=Path), help="World file (SPEC §7).")
@click.option("--drones", "n", type=click.IntRange(1, 100), help="Number of drones (default: the world's, or 1).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the script's `random`.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), help="Write result.json, recording.mcap and plots here.")
@click.option("--max-time", "max_s", type=click.FloatRange(1, 86_400), default=3600, show_default=True,
              help="Cancel the mission after this much simulated time (s).")
@click.option("--enable", "plugins", multiple=True, metavar="'PLUGIN key=value…'",
              help="Enable a plugin before the script's first line, e.g. --enable 'replacement drainage=0.0015' (repeatable).")
@click.option("--plugins-dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Also load the plugin scripts in this directory (besides the bundled ones).")
@click.option("--no-plots", is_flag=True, help="With --out: result.json and the recording only, no PNG plots.")
@click.option("--radio/--no-radio", default=None,
              help="Fly on the radio model (SPEC §8: links lost with distance, relayed by drones). "
                   "Default: on if the world file has `radio:`.")
@click.option("--limit-memory-mb", type=click.IntRange(16), hidden=True,
              help="As a mission's sandbox: the memory the run may allocate beyond its own (the ground's preflight).")
@click.option("--limit-cpu-s", type=click.FloatRange(1), hidden=True, help="As a mission's sandbox: CPU seconds in all.")
@click.option("--predicting", is_flag=True, hidden=True,
              help="As the ground's preflight: the world is a copy of the live fleet; result.json names the first "
                   "line that reads what the copy cannot know (a sensor, the field sensors, the radio).")
def simulate(script: Path, inputs: tuple[str, ...], world: Path | None, n: int | None, seed: int, out_dir: Path | None,
             max_s: float, plugins: tuple[str, ...], plugins_dir: Path | None, no_plots: bool, radio: bool | None,
             limit_memory_mb: int | None, limit_cpu_s: float | None, predicting: bool) -> None:
    """Run SCRIPT against simulated drones in fast time; exit with its outcome.

    Plugin inputs go with --enable in one word (--enable 'replacement drainage=0.0015')
    or, with a single --enable, as key=value words after it (SPEC §5)."""
    import logging

    from dronefleet.compose import simulate as run
    from dronefleet.mission.script.checks import first_problem
    from dronefleet.mission.script.plugins import PluginLibrary, parse_enable, plugin_summary
    from dronefleet.mission.script.sandbox import ScriptError
    from dronefleet.schemas.config_loading import writable_dir
    from dronefleet.sim.world import load_world

    library = PluginLibrary.default(plugins_dir)
    if library.failures:
        click.echo(plugin_summary(library).replace("fleet ground: ", ""), err=True)
    enable: dict[str, dict[str, object]] = {}
    if inputs:
        if len(plugins) != 1:
            _fail(f"unexpected arguments {' '.join(inputs)}: key=value inputs after SCRIPT need exactly one --enable", 2)
        plugins = (" ".join((plugins[0], *inputs)),)
    for text in plugins:
        try:
            plugin_id, plugin_inputs = parse_enable(text)
        except ValueError as exc:
            _fail(str(exc), 2)
        if library.get(plugin_id) is None:
            _fail(f"--enable: no plugin {plugin_id!r} (loaded: {', '.join(sorted(library.plugins)) or 'none'})", 2)
        enable[plugin_id] = plugin_inputs
    source = _read_script(script)
    try:
        first_problem(source, str(script), library.verbs())
    except ScriptError as exc:
        _fail(f"{script}:{exc.line}:{exc.column}: {exc.message}")
    if not logging.getLogger().isEnabledFor(logging.DEBUG):  # the mission's own lines are echoed
        for name in ("dronefleet.ground", "dronefleet.mission", "dronefleet.agent", "matplotlib"):
            logging.getLogger(name).setLevel(logging.WARNING)
    field = load_world(world)
    if out_dir is not None:
        writable_dir(out_dir, "--out")  # before the run, not after it
    if radio is not None:
        field = msgspec.structs.replace(field, radio=field.radio_model if radio else None)
    if limit_memory_mb is not None or limit_cpu_s is not None:
        import faulthandler
        import signal

        from dronefleet.mission.hosting.worker import limit_self

        # SIGUSR1 prints every thread's stack, even from inside a C call: the line a
        # script had reached when its bound ended it (ground/planning.py).
        faulthandler.register(signal.SIGUSR1, all_threads=True)
        limit_self(limit_memory_mb or 1_048_576, limit_cpu_s or 1e9)
    started = time.perf_counter()
    if predicting:  # the ground's bound on the preflight counts from here (ground/planning.py)
        click.echo("simulating")
    try:
        result = asyncio.run(run(
            source, field, n=n, seed=seed, out_dir=out_dir, name=script.name, max_s=max_s,
            echo=lambda t, message: click.echo(f"[{t:8.1f} s] {message}"), plugins=library, enable=enable,
            plots=not no_plots, predicting=predicting,
        ))
    except ScriptError as exc:
        _fail(f"{script}:{exc.line}:{exc.column}: {exc.message}")
    record = result["mission"]
    duration = ((record.get("end") or 0) - (record.get("start") or 0)) / 1000
    wall = time.perf_counter() - started
    click.echo(outcome(record))
    click.echo(f"simulated {duration:.1f} s in {wall:.2f} s of wall time ({duration / max(wall, 1e-9):.0f}x)")
    if out_dir is not None:
        click.echo(f"wrote result.json, recording.mcap{'' if no_plots else ' and plots'} in {out_dir}")
    raise SystemExit(EXIT_CODES[record["status"]])
