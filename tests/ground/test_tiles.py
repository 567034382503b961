"""Maps with no internet (issue 54): `fleet tiles fetch` against a tile server started
here writes a PMTiles archive holding exactly the tiles of the box and zooms; an
interrupted fetch resumes without asking again for what it has; a server error is asked
again and then named; the ground serves the archive's tiles and refuses a bad
`dashboard.tiles` at start."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import mercantile
import pytest

from dronefleet.ground.config import GroundConfig
from dronefleet.ground.dashboard_routes import open_tile_archive
from dronefleet.ground.tile_archive import TileArchive
from dronefleet.ground.tile_fetch import FetchError, fetch, parse_zooms, tiles_of
from dronefleet.schemas.config_loading import load_config
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.geo import Box
from tests.dashboard.tiles import TileServer
from tests.harness import GroundProcess

pytestmark = pytest.mark.integration

BOX = Box(47.3970, 8.5440, 47.3990, 8.5470)  # a field of 220 x 230 m
ZOOMS = range(15, 18)


@pytest.fixture
def server() -> Iterator[TileServer]:
    tiles = TileServer()
    yield tiles
    tiles.close()


def no_wait(seconds: float) -> None:
    pass


def test_an_archive_holds_exactly_the_tiles_of_the_box_and_zooms(server: TileServer, tmp_path: Path) -> None:
    out = tmp_path / "field.pmtiles"
    done = fetch(server.template, BOX, ZOOMS, out, attribution="© test tiles", rate_per_s=50)
    wanted = {(t.z, t.x, t.y) for t in tiles_of(BOX, ZOOMS)}
    assert set(server.requested) == wanted and len(server.requested) == len(wanted)  # each once, nothing else
    assert (done.tiles, done.missing, done.requested) == (len(wanted), 0, len(wanted))
    archive = TileArchive(out)
    try:
        assert all(archive.tile(*t) is not None for t in wanted)
        outside = mercantile.tile(BOX.west - 0.01, BOX.south - 0.01, 16)
        assert archive.tile(outside.z, outside.x, outside.y) is None
        assert (archive.min_zoom, archive.max_zoom, archive.attribution) == (15, 17, "© test tiles")
        assert archive.summary()["tiles"] == len(wanted) and archive.media_type == "image/png"
    finally:
        archive.close()
    assert not (tmp_path / "field.pmtiles.part").exists()


def test_an_interrupted_fetch_resumes_without_asking_again_for_what_it_has(server: TileServer, tmp_path: Path) -> None:
    out = tmp_path / "field.pmtiles"
    server.serve_at_most = 5  # then every answer is 503: the server gone
    with pytest.raises(FetchError, match=r"failed 2 times \(HTTP 503\); stopped"):
        fetch(server.template, BOX, ZOOMS, out, rate_per_s=50, retries=1, sleep=no_wait)
    assert not out.exists() and (tmp_path / "field.pmtiles.part").exists()
    server.serve_at_most, server.requested = None, []
    done = fetch(server.template, BOX, ZOOMS, out, rate_per_s=50, sleep=no_wait)
    total = len(tiles_of(BOX, ZOOMS))
    assert done.tiles == total and done.requested == total - 5 == len(set(server.requested))


def test_a_server_error_is_asked_again_then_named_and_a_refusal_stops_at_once(server: TileServer, tmp_path: Path) -> None:
    first = tiles_of(BOX, ZOOMS)[0]
    server.answers[(first.z, first.x, first.y)] = [500, 502]  # then 200
    pauses: list[float] = []
    done = fetch(server.template, BOX, ZOOMS, tmp_path / "a.pmtiles", rate_per_s=50, retries=3, sleep=pauses.append)
    assert done.tiles == len(tiles_of(BOX, ZOOMS)) and server.requested.count((first.z, first.x, first.y)) == 3
    assert [p for p in pauses if p >= 1.0] == [1.0, 2.0]  # paused, longer each time
    server.answers[(first.z, first.x, first.y)] = [403]
    with pytest.raises(FetchError, match=rf"tile {first.z}/{first.x}/{first.y}: http://127.0.0.1:\d+/.* answered HTTP 403"):
        fetch(server.template, BOX, ZOOMS, tmp_path / "b.pmtiles", rate_per_s=50, sleep=no_wait)


def test_the_command_says_the_size_first_and_info_says_what_an_archive_covers(server: TileServer, tmp_path: Path) -> None:
    out = tmp_path / "field.pmtiles"
    bbox = f"{BOX.south},{BOX.west},{BOX.north},{BOX.east}"
    fleet = [sys.executable, "-m", "dronefleet", "tiles"]
    fetched = subprocess.run([*fleet, "fetch", "--bbox", bbox, "--zoom", "15-17", "--url", server.template, "--out",
                              str(out), "--rate", "50", "--attribution", "© test tiles"],
                             capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    total = len(tiles_of(BOX, ZOOMS))
    assert fetched.returncode == 0, fetched.stderr
    assert fetched.stdout.startswith(f"{total} tiles at zooms 15-17, about "), fetched.stdout
    assert f"wrote {out}: {total} tiles" in fetched.stdout
    info = subprocess.run([*fleet, "info", str(out), "--json"], capture_output=True, text=True, timeout=60,
                          stdin=subprocess.DEVNULL)
    summary = json.loads(info.stdout)
    assert (summary["tiles"], summary["min_zoom"], summary["max_zoom"], summary["attribution"]) == (total, 15, 17, "© test tiles")
    bad = subprocess.run([*fleet, "fetch", "--bbox", "47.4,8.5,47.3,8.6", "--url", server.template, "--out", str(out)],
                         capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert bad.returncode == 2 and "--bbox 47.4,8.5,47.3,8.6: south below north" in bad.stderr, bad.stderr


def test_zooms_and_boxes_are_read_or_refused_by_name() -> None:
    assert parse_zooms("12-18") == range(12, 19) and parse_zooms("15") == range(15, 16)
    for text in ("18-12", "a-b", "0-30"):
        with pytest.raises(ValueError, match="--zoom"):
            parse_zooms(text)
    with pytest.raises(ValueError, match="--bbox takes S,W,N,E"):
        Box.parse("1,2,3")


async def test_the_ground_serves_an_archives_tiles_and_refuses_a_bad_one_at_start(server: TileServer,
                                                                                 tmp_path: Path) -> None:
    out = tmp_path / "field.pmtiles"
    fetch(server.template, BOX, ZOOMS, out, attribution="© test tiles", rate_per_s=50)
    ground = GroundProcess(tmp_path, dashboard={"tiles": str(out)})
    try:
        await ground.ready()
        async with httpx.AsyncClient(base_url=ground.url, timeout=10) as http:
            config = (await http.get("/dashboard/config.json")).json()
            assert (config["tiles"], config["tiles_max_zoom"], config["attribution"]) == ("/tiles/{z}/{x}/{y}", 17, "© test tiles")
            t = tiles_of(BOX, ZOOMS)[-1]
            tile = await http.get(f"/tiles/{t.z}/{t.x}/{t.y}")
            assert tile.status_code == 200 and tile.headers["content-type"] == "image/png" and tile.content[:4] == b"\x89PNG"
            assert (await http.get("/tiles/18/0/0")).status_code == 404
    finally:
        ground.stop()
    (tmp_path / "not-tiles.pmtiles").write_text("hello")
    for tiles, why in ((str(tmp_path / "absent.pmtiles"), "No such file"), (str(tmp_path / "not-tiles.pmtiles"), "not a PMTiles archive")):
        config = load_config(GroundConfig, None, {"dashboard": {"tiles": tiles}})
        with pytest.raises(ConfigError, match=f"dashboard.tiles: .*{why}"):
            open_tile_archive(config)


def _pixels(png: bytes) -> Any:
    """A PNG's pixels, RGB(A) in 0..1 (matplotlib, imported here: every pytest worker
    collects this module, and matplotlib with numpy is a fifth of a collection)."""
    from matplotlib import image

    return image.imread(io.BytesIO(png), format="png")


def _rgb(png: bytes, row: int, col: int) -> tuple[float, float, float]:
    pixel = _pixels(png)[row, col]
    return float(pixel[0]), float(pixel[1]), float(pixel[2])


def test_a_world_is_drawn_as_a_map_with_its_fire_and_its_ring_at_every_zoom(tmp_path: Path) -> None:
    """`fleet tiles render WORLD`: the map `fleet demo` shows, with no tile server. Every
    tile of the world's box at every zoom; the tile over the heat source's centre is
    warm there, the ring where the field crosses 40 °C is drawn, and the field far from
    the source is plain ground."""
    fire = (40.6340, -8.6600)
    world = tmp_path / "w.yml"
    world.write_text(json.dumps({
        "origin": {"lat": 40.6335, "lon": -8.6608, "alt": 8.2},
        "drones": [{"id": "drone01", "lat": 40.6335, "lon": -8.6608}],
        "heat_sources": [{"lat": fire[0], "lon": fire[1], "radius": 40, "temp": 60}],
    }))
    out = tmp_path / "map.pmtiles"
    made = subprocess.run([sys.executable, "-m", "dronefleet", "tiles", "render", str(world), "--out", str(out),
                           "--zoom", "16-19"], capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert made.returncode == 0, made.stderr
    archive = TileArchive(out)
    try:
        assert (archive.min_zoom, archive.max_zoom) == (16, 19)
        assert "drawn from w.yml" in archive.attribution
        s, w, n, e = archive.summary()["bounds"]
        assert s < min(40.6335, fire[0]) and n > max(40.6335, fire[0]) and w < -8.6608 and e > -8.6600
        box = Box(s, w, n, e)
        assert archive.summary()["tiles"] == len(tiles_of(box, range(16, 20)))
        for z in range(16, 20):
            centre = mercantile.tile(fire[1], fire[0], z)
            png = archive.tile(z, centre.x, centre.y)
            assert png is not None and png.startswith(b"\x89PNG")
            left, bottom, right, top = mercantile.bounds(centre)
            col = int((fire[1] - left) / (right - left) * 256)
            row = int((top - fire[0]) / (top - bottom) * 256)  # near enough in a tile this small
            r, g, b = _rgb(png, row, col)
            assert r > 0.85 and b < 0.4, (z, r, g, b)  # warm at the centre
        corner = mercantile.tile(w + 1e-5, s + 1e-5, 19)
        png = archive.tile(19, corner.x, corner.y)
        assert png is not None
        r, g, b = _rgb(png, 128, 128)
        assert g >= r and b > 0.7, (r, g, b)  # plain ground, far from the fire
        ring = archive.tile(17, *mercantile.tile(fire[1], fire[0], 17)[:2])
        assert ring is not None
        pixels = _pixels(ring)
        dark_red = (pixels[..., 0] > 0.5) & (pixels[..., 1] < 0.2)
        assert dark_red.sum() > 20  # the 40 °C ring: 20 m out at this source, a circle of pixels
    finally:
        archive.close()
    bad = subprocess.run([sys.executable, "-m", "dronefleet", "tiles", "render", str(world), "--out", str(out),
                          "--zoom", "19-16"], capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert bad.returncode == 2 and "--zoom 19-16" in bad.stderr, bad.stderr
