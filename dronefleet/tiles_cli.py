"""`fleet tiles fetch` and `fleet tiles info`: maps for a field with no internet (issue 54)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from dronefleet.cli_kit import fail


@click.group()
def tiles() -> None:
    """Map tiles in one file (PMTiles) for the dashboard with no internet: `dashboard.tiles: FILE`."""


@tiles.command("fetch")
@click.option("--bbox", required=True, help="The box to cover: S,W,N,E in degrees, e.g. 40.63,-8.67,40.65,-8.65.")
@click.option("--zoom", "zoom", default="12-18", show_default=True, help="Zooms to fetch, FIRST-LAST.")
@click.option("--url", "template", required=True,
              help="The tile server's URL template with {z}, {x}, {y}; use one whose terms allow it.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="The archive to write (.pmtiles).")
@click.option("--attribution", default="", help="The map's credit, stored in the archive and shown on the map, "
                                                 "e.g. '© OpenStreetMap contributors'.")
@click.option("--rate", "rate_per_s", type=click.FloatRange(min=0.1, max=50), default=2.0, show_default=True,
              help="Requests a second at most (tile servers' usage policies ask for a polite rate).")
@click.option("--retries", type=click.IntRange(0, 10), default=3, show_default=True,
              help="Times a tile is asked again after a 429, a 5xx or a timeout.")
def fetch_tiles(bbox: str, zoom: str, template: str, out: Path, attribution: str, rate_per_s: float, retries: int) -> None:
    """Fetch the tiles of a box into one archive, with a progress bar.

    Says how many tiles and about how many megabytes before it starts. Interrupted
    (Ctrl-C, a server error, the connection gone), it keeps what it has in OUT.part:
    the same command goes on from there.
    """
    from dronefleet.ground.config import missing_placeholders
    from dronefleet.ground.tile_archive import TileArchiveError
    from dronefleet.ground.tile_fetch import TYPICAL_TILE_BYTES, FetchError, fetch, parse_zooms, tiles_of
    from dronefleet.schemas.geo import Box

    if missing_placeholders(template):
        fail(f"--url must contain {{z}}, {{x}} and {{y}}, e.g. https://tiles.example/{{z}}/{{x}}/{{y}}.png (got {template})", 2)
    try:
        box, zooms = Box.parse(bbox), parse_zooms(zoom)
    except ValueError as exc:
        fail(str(exc), 2)
    count = len(tiles_of(box, zooms))
    click.echo(f"{count} tiles at zooms {zooms.start}-{zooms.stop - 1}, about {count * TYPICAL_TILE_BYTES / 1e6:.1f} MB, "
               f"at most {rate_per_s:g} a second (about {count / rate_per_s / 60:.0f} min from scratch)")
    try:
        with click.progressbar(length=count, label="fetching", show_pos=True, show_eta=True) as bar:
            done = fetch(template, box, zooms, out, attribution=attribution, rate_per_s=rate_per_s, retries=retries,
                         progress=bar.update)
    except (FetchError, TileArchiveError, OSError) as exc:
        fail(str(exc))
    click.echo(f"wrote {out}: {done.tiles} tiles ({out.stat().st_size / 1e6:.1f} MB), {done.missing} the server "
               f"does not have; {done.requested} requested in this run")


@tiles.command("render")
@click.argument("world_file", metavar="WORLD", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="The archive to write (.pmtiles).")
@click.option("--zoom", "zoom", default="15-19", show_default=True, help="Zooms to draw, FIRST-LAST.")
@click.option("--margin", "margin_m", type=click.FloatRange(min=0, max=5000), default=250.0, show_default=True,
              help="Metres of map beyond the world's drones, sources and laptop.")
def render_tiles(world_file: Path, out: Path, zoom: str, margin_m: float) -> None:
    """Draw a world's field as a map archive, with no internet and no tile server.

    The map shows what the world file knows (its heat sources and the 40 °C ring, its
    other fields' areas, a line every 50 m from the laptop) on a plain ground colour:
    `fleet demo` draws one for its world, and `dashboard.tiles: OUT` shows it.
    """
    from dronefleet.ground.tile_fetch import parse_zooms

    try:
        zooms = parse_zooms(zoom)
    except ValueError as exc:
        fail(str(exc), 2)
    count = write_world_map(world_file, out, zooms, margin_m)
    click.echo(f"wrote {out}: {count} tiles at zooms {zooms.start}-{zooms.stop - 1} ({out.stat().st_size / 1e6:.2f} MB)")


def write_world_map(world_file: Path, out: Path, zooms: range, margin_m: float = 250.0) -> int:
    """`fleet tiles render`: the world's map as a PMTiles archive at `out`; how many tiles."""
    from dronefleet.ground.tile_archive import TileArchiveError, write_archive
    from dronefleet.schemas.errors import FleetError
    from dronefleet.sim.map_tiles import render, world_box
    from dronefleet.sim.world import load_world

    world = load_world(world_file)  # a ConfigError names the key
    box = world_box(world, margin_m)
    try:
        return write_archive(out, render(world, zooms, box), (box.south, box.west, box.north, box.east),
                             {"attribution": f"Fleet: drawn from {world_file.name} (no imagery)", "source": str(world_file)})
    except TileArchiveError as exc:
        raise FleetError(f"{out}: {exc}") from None


@tiles.command("info")
@click.argument("archive", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of lines.")
def tiles_info(archive: Path, as_json: bool) -> None:
    """What ARCHIVE covers: zooms, bounds, tiles, attribution."""
    from dronefleet.ground.tile_archive import TileArchive, TileArchiveError

    try:
        opened = TileArchive(archive)
    except TileArchiveError as exc:
        fail(str(exc), 2)
    summary = opened.summary()
    opened.close()
    if as_json:
        click.echo(json.dumps(summary))
        return
    s, w, n, e = summary["bounds"]
    click.echo(f"{archive}: {summary['tiles']} tiles ({summary['media_type']}), zooms {summary['min_zoom']}-"
               f"{summary['max_zoom']}, bounds S {s:.5f} W {w:.5f} N {n:.5f} E {e:.5f}, {summary['bytes'] / 1e6:.1f} MB")
    click.echo(f"attribution: {summary['attribution'] or '(none stored)'}")
    if summary["source"]:
        click.echo(f"fetched from: {summary['source']}")
