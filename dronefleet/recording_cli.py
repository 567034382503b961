"""`fleet record`, `fleet replay`, `fleet plot` (SPEC §12): recordings of the mesh in MCAP."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import click

from dronefleet.cli_kit import ENDPOINT, run_async, secured_client, with_pki

CONNECT = click.option("--connect", multiple=True, type=ENDPOINT, default=["tcp/127.0.0.1:7447"], show_default=True,
                       help="Zenoh endpoint of the mesh (repeatable).")


def _summary(messages: int, channels: int, seconds: float) -> str:
    return f"{messages} messages on {channels} channels over {seconds:.1f} s"


@click.command()
@click.argument("keyexprs", nargs=-1)
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path),
              help="The MCAP file to write (default: fleet-<date>-<time>.mcap here).")
@CONNECT
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), help="Stop after this many seconds (default: Ctrl-C).")
@click.option("--recover", "broken", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Do not record: rewrite this cut recording (its recorder was killed) as a complete file at --out.")
@with_pki
def record(keyexprs: tuple[str, ...], out: Path | None, connect: tuple[str, ...], duration: float | None,
           broken: Path | None, pki_dir: Path | None, cert_name: str) -> None:
    """Write every message on the mesh (or under KEYEXPRS) to an MCAP file.

    One channel per key, a JSON schema per message kind; liveliness tokens are
    `fleet.Liveliness` messages on their keys. Ctrl-C (or --duration) closes the file;
    a recorder that is killed loses at most its last second (`fleet record --recover`).
    """
    from dronefleet.bus.recording import Recorder, record_until_stopped, recover
    from dronefleet.bus.zenoh_bus import ZenohBus

    if broken is not None:
        target = out or broken.with_suffix(".recovered.mcap")
        contents = recover(broken, target)
        state = "was complete" if contents.complete else "was cut short"
        click.echo(f"wrote {target}: {len(contents.messages)} messages ({broken} {state})")
        return
    extra = secured_client(pki_dir, cert_name, list(connect))
    out = out or Path(time.strftime("fleet-%Y%m%d-%H%M%S.mcap"))
    recorder = Recorder(out)
    started = time.monotonic()
    click.echo(f"recording {', '.join(keyexprs) or '**'} from {', '.join(connect)} to {out} (Ctrl-C to stop)")

    async def main() -> None:
        bus = await ZenohBus.open("client", list(connect), extra=extra)
        stop = asyncio.Event()
        if duration is not None:
            asyncio.get_running_loop().call_later(duration, stop.set)
        try:
            await record_until_stopped(bus, recorder, keyexprs or ("**",), stop)
        finally:
            stop.set()
            await bus.close()

    try:
        run_async(main())
    finally:
        recorder.close()
        click.echo(f"wrote {out}: {recorder.messages} messages in {time.monotonic() - started:.1f} s")


@click.command()
@click.argument("path", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--speed", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Play this many times faster than recorded.")
@CONNECT
@click.option("--hold", is_flag=True, help="At the end, keep the drones' liveliness until Ctrl-C.")
@with_pki
def replay(path: Path, speed: float, connect: tuple[str, ...], hold: bool, pki_dir: Path | None, cert_name: str) -> None:
    """Publish a recording on the mesh again, with its timing (so `fleet ground` and
    the dashboard show a past flight). Commands and bundles are never replayed."""
    from dronefleet.bus.clock import SystemClock
    from dronefleet.bus.recording import Replay, read
    from dronefleet.bus.zenoh_bus import ZenohBus

    extra = secured_client(pki_dir, cert_name, list(connect))
    contents = read(path)
    if not contents.complete:
        click.echo(f"note: {path} was cut short (its recorder was killed); replaying the {len(contents.messages)} "
                   "messages it holds", err=True)
    shown = [0.0]

    def progress(done: int, total: int) -> None:
        now = time.monotonic()
        if now - shown[0] >= 5 or done == total:
            shown[0] = now
            click.echo(f"replayed {done}/{total} messages")

    async def main() -> None:
        bus = await ZenohBus.open("client", list(connect), extra=extra)
        player = Replay(bus, contents, SystemClock(), speed)
        try:
            await player.run(progress)
            if hold:
                click.echo("holding the drones' liveliness (Ctrl-C to stop)")
                await asyncio.Event().wait()
        finally:
            player.close()
            await bus.close()

    run_async(main())


@click.command()
@click.argument("path", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Where to write the PNGs (default: beside PATH).")
def plot(path: Path, out_dir: Path | None) -> None:
    """Draw the plots of SPEC §5 (paths, altitude, battery, distances, link) from a
    recording (.mcap) or a simulation's result.json."""
    from dronefleet.mission.hosting.plots import write_plots

    if path.suffix == ".json":
        try:
            result = json.loads(path.read_text())
            result["drones"]  # noqa: B018 — the shape of a result.json
        except (ValueError, KeyError, TypeError) as exc:
            raise click.BadParameter(f"{path} is not a simulation's result.json ({exc})", param_hint="PATH") from None
    else:
        from dronefleet.bus.recording import RecordingError, read
        from dronefleet.ground.mission_recording import result_of_recording

        try:
            result = result_of_recording(read(path))
        except RecordingError as exc:
            raise click.BadParameter(str(exc), param_hint="PATH") from None
    if not any(d["samples"] for d in result["drones"].values()):
        raise click.BadParameter(f"{path} holds no telemetry with a position: nothing to draw", param_hint="PATH")
    out_dir = out_dir or path.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    for written in write_plots(result, out_dir):
        click.echo(f"wrote {written}")
