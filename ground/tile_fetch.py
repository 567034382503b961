"""Preparing a map for a field with no internet (issue 54): the tiles of a box and of a
range of zooms, fetched from a tile server while a connection exists, kept as they come
so an interrupted fetch resumes, then written as one PMTiles archive
(ground/tile_archive.py). Tile maths with `mercantile`.

Polite to the server: at most `rate_per_s` requests a second, one at a time, a
User-Agent naming Fleet; a 429 or 5xx answer or a timeout is asked again after a pause
(growing), up to `retries` times, then named; a 404 is a tile the server does not have
(kept as such, never asked again); any other answer stops the fetch, named.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import httpx
import mercantile

from dronefleet.ground.tile_archive import write_archive
from dronefleet.schemas.geo import Box

USER_AGENT = "Fleet tile fetch (offline maps for a drone field; https://pypi.org/project/dronefleet/)"
TYPICAL_TILE_BYTES = 20_000  # a raster map tile, for the estimate before a fetch starts
RETRY_PAUSE_S = 1.0  # the first pause before asking again; doubled each time


class FetchError(Exception):
    """The fetch stopped (the message names the tile, its URL and what the server said);
    what it had is kept for the next run."""


def parse_zooms(text: str) -> range:
    """`12-18` or `15`."""
    lo, _, hi = text.partition("-")
    try:
        first, last = int(lo), int(hi or lo)
    except ValueError:
        raise ValueError(f"--zoom takes FIRST-LAST (e.g. 12-18), not {text!r}") from None
    if not 0 <= first <= last <= 22:
        raise ValueError(f"--zoom {text}: zooms run 0-22, the first not above the last")
    return range(first, last + 1)


def tiles_of(box: Box, zooms: Sequence[int]) -> list[mercantile.Tile]:
    return list(mercantile.tiles(box.west, box.south, box.east, box.north, list(zooms)))


def _url(template: str, tile: mercantile.Tile) -> str:
    return template.replace("{z}", str(tile.z)).replace("{x}", str(tile.x)).replace("{y}", str(tile.y))


class TileStore:
    """What a fetch has so far (`<out>.part`, SQLite): tiles and the ones the server lacks."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.db = sqlite3.connect(path)
        self.db.execute("CREATE TABLE IF NOT EXISTS tiles (z INTEGER, x INTEGER, y INTEGER, data BLOB, PRIMARY KEY (z, x, y))")
        self.db.execute("CREATE TABLE IF NOT EXISTS missing (z INTEGER, x INTEGER, y INTEGER, PRIMARY KEY (z, x, y))")
        self.db.commit()

    def done(self) -> set[tuple[int, int, int]]:
        rows = self.db.execute("SELECT z, x, y FROM tiles UNION SELECT z, x, y FROM missing").fetchall()
        return {(int(z), int(x), int(y)) for z, x, y in rows}

    def put(self, tile: mercantile.Tile, data: bytes | None) -> None:
        if data is None:
            self.db.execute("INSERT OR REPLACE INTO missing VALUES (?, ?, ?)", (tile.z, tile.x, tile.y))
        else:
            self.db.execute("INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?)", (tile.z, tile.x, tile.y, data))
        self.db.commit()

    def rows(self) -> list[tuple[int, int, int, bytes]]:
        return [(int(z), int(x), int(y), bytes(d)) for z, x, y, d in self.db.execute("SELECT z, x, y, data FROM tiles")]

    def close(self) -> None:
        self.db.close()


@dataclass
class Fetched:
    tiles: int  # in the archive
    missing: int  # the server had none there (404)
    requested: int  # asked of the server in this run (a resumed run asks only what it lacked)


def fetch(template: str, box: Box, zooms: Sequence[int], out: Path, *, attribution: str = "", rate_per_s: float = 2.0,
          retries: int = 3, timeout_s: float = 20.0, progress: Callable[[int], None] = lambda n: None,
          client: httpx.Client | None = None, sleep: Callable[[float], None] = time.sleep) -> Fetched:
    """Fetch every tile of `box` at `zooms` into `out` (PMTiles). `progress(n)` is called
    with each tile done, fetched now or found from an earlier run."""
    wanted = tiles_of(box, zooms)
    store = TileStore(out.with_name(out.name + ".part"))
    own = client is None
    http = client or httpx.Client(headers={"User-Agent": USER_AGENT}, timeout=timeout_s, follow_redirects=True)
    requested = 0
    try:
        have = store.done()
        progress(sum(1 for t in wanted if (t.z, t.x, t.y) in have))
        last = 0.0
        for tile in wanted:
            if (tile.z, tile.x, tile.y) in have:
                continue
            pause = RETRY_PAUSE_S
            for attempt in range(retries + 1):
                wait = last + 1.0 / rate_per_s - time.monotonic()
                if wait > 0:
                    sleep(wait)
                last = time.monotonic()
                requested += 1
                url = _url(template, tile)
                try:
                    reply = http.get(url)
                except httpx.HTTPError as exc:
                    why = f"{type(exc).__name__}: {exc}"
                else:
                    if reply.status_code == 200:
                        store.put(tile, reply.content)
                        break
                    if reply.status_code == 404:
                        store.put(tile, None)
                        break
                    why = f"HTTP {reply.status_code}"
                    if reply.status_code != 429 and reply.status_code < 500:
                        raise FetchError(f"tile {tile.z}/{tile.x}/{tile.y}: {url} answered {why}; stopped "
                                         "(what was fetched is kept: the same command goes on from there)")
                if attempt == retries:
                    raise FetchError(f"tile {tile.z}/{tile.x}/{tile.y}: {url} failed {retries + 1} times ({why}); "
                                     "stopped (what was fetched is kept: the same command goes on from there)")
                sleep(pause)
                pause *= 2
            progress(1)
        rows = store.rows()
        if not rows:
            raise FetchError(f"the server had none of the {len(wanted)} tiles (every one answered 404): check --url")
        missing = len(wanted) - len(rows)
        count = write_archive(out, rows, (box.south, box.west, box.north, box.east),
                              {"attribution": attribution, "source": template, "name": out.stem})
    finally:
        if own:
            http.close()
        store.close()
    store.path.unlink()
    return Fetched(tiles=count, missing=missing, requested=requested)
