"""Maps with no internet (issue 54): `fleet tiles fetch` against a tile server started
here writes a PMTiles archive holding exactly the tiles of the box and zooms; an
interrupted fetch resumes without asking again for what it has; a server error is asked
again and then named; the ground serves the archive's tiles and refuses a bad
`dashboard.tiles` at start."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import mercantile
import pytest

from dronefleet.ground.config import GroundConfig
from dronefleet.ground.dashboard_routes import open_tile_archive
from dronefleet.ground.tile_archive import TileArchive
from dronefleet.ground.tile_fetch import Box, FetchError, fetch, parse_zooms, tiles_of
from dronefleet.schemas.config import load_config
from dronefleet.schemas.errors import ConfigError
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
