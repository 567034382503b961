"""The web dashboard's routes (SPEC §10): the files of `ground/dashboard/`, read from
the installed package, `GET /` (or the map of the API, for a client asking for JSON),
`/dashboard/config.json` with what the page draws besides the drones, and `/tiles/…`
when `dashboard.tiles` names a PMTiles archive (a field with no internet)."""

from __future__ import annotations

import logging
from importlib import resources
from pathlib import Path, PurePath
from typing import Any

import msgspec
from litestar import Request, Response, get

from dronefleet.ground.api_error import ApiError
from dronefleet.ground.config import GroundConfig, HeatMark, MapSpot
from dronefleet.ground.station import GroundStation
from dronefleet.ground.tile_archive import TileArchive, TileArchiveError
from dronefleet.schemas.errors import ConfigError
from dronefleet.schemas.fence import Geofence

log = logging.getLogger(__name__)


_ASSET_TYPES = {
    ".html": "text/html; charset=utf-8", ".css": "text/css; charset=utf-8",
    ".js": "text/javascript; charset=utf-8", ".svg": "image/svg+xml",
}
# The page is small and changes only with the package: served from memory, always
# revalidated (an upgraded ground is never shown with yesterday's scripts).
_ASSET_HEADERS = {"Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff"}


class DashboardAssets:
    """The files of `ground/dashboard/`, read once, by name."""

    def __init__(self, files: dict[str, tuple[bytes, str]]) -> None:
        self.files = files

    @classmethod
    def load(cls) -> DashboardAssets:
        root = resources.files("dronefleet.ground") / "dashboard"
        if not root.is_dir():  # an install without its package data: the API still serves
            log.warning("the dashboard's files are not installed (%s): GET / answers 404", root)
            return cls({})
        return cls({
            f.name: (f.read_bytes(), _ASSET_TYPES[suffix]) for f in root.iterdir()
            if f.is_file() and (suffix := PurePath(f.name).suffix) in _ASSET_TYPES
        })

    def response(self, name: str) -> Response[Any]:
        if name not in self.files:
            return Response(ApiError(error=f"no dashboard file {name!r}", detail={"file": name}), status_code=404)
        content, media_type = self.files[name]
        return Response(content, media_type=media_type, headers=_ASSET_HEADERS)


ARCHIVE_TILES = "/tiles/{z}/{x}/{y}"
_TILE_HEADERS = {"Cache-Control": "max-age=86400", "X-Content-Type-Options": "nosniff"}


def open_tile_archive(config: GroundConfig) -> TileArchive | None:
    """The archive `dashboard.tiles` names, opened; a clear error naming the key if it
    cannot be (checked at start, not when the first page asks)."""
    path = config.dashboard.tiles_archive
    if path is None:
        return None
    try:
        return TileArchive(Path(path).expanduser())  # relative: to where the ground was started
    except TileArchiveError as exc:
        raise ConfigError(f"dashboard.tiles: {exc}") from None


class TileSource:
    """The archive the ground serves tiles from, if any (a dependency of the routes)."""

    def __init__(self, archive: TileArchive | None) -> None:
        self.archive = archive


class DashboardConfig(msgspec.Struct, frozen=True, kw_only=True):
    """GET /dashboard/config.json: what the page draws besides the drones."""

    tiles: str | None
    tiles_max_zoom: int | None  # the deepest zoom the tiles exist at (an archive's; None: the server's, unknown)
    attribution: str
    event_telemetry_ms: int
    geofence: Geofence
    ground_station: MapSpot | None
    heat_sources: list[HeatMark]


_INDEX = {
    "name": "fleet ground", "dashboard": "/", "openapi": "/openapi.json", "drones": "/drone", "missions": "/mission",
    "plugins": "/plugin", "events": "/events", "logs": "/drone/logs",
}


@get("/", sync_to_thread=False, include_in_schema=False)
def index(request: Request[Any, Any, Any], assets: DashboardAssets) -> Response[Any]:
    """The dashboard; a client asking for JSON gets the map of the API instead."""
    if request.accept.best_match(["text/html", "application/json"], "text/html") == "application/json":
        return Response(_INDEX)
    return assets.response("index.html")


@get("/dashboard/config.json", sync_to_thread=False, include_in_schema=False)
def dashboard_config(station: GroundStation, tile_source: TileSource) -> DashboardConfig:
    c = station.config
    archive = tile_source.archive
    attribution = c.dashboard.attribution if c.dashboard.attribution is not None else (archive.attribution if archive else "")
    return DashboardConfig(
        tiles=ARCHIVE_TILES if archive else c.dashboard.tiles, tiles_max_zoom=archive.max_zoom if archive else None,
        attribution=attribution, event_telemetry_ms=c.event_telemetry_ms, geofence=c.geofence,
        ground_station=c.dashboard.ground_station, heat_sources=c.dashboard.heat_sources,
    )


@get("/tiles/{z:int}/{x:int}/{y:int}", sync_to_thread=False, include_in_schema=False)
def map_tile(tile_source: TileSource, z: int, x: int, y: int) -> Response[Any]:
    """A tile of the archive `dashboard.tiles` names; 404 where it holds none (the page
    then scales the nearest one it has)."""
    archive = tile_source.archive
    data = archive.tile(z, x, y) if archive is not None else None
    if data is None:
        return Response(ApiError(error=f"no map tile {z}/{x}/{y}", detail={"z": z, "x": x, "y": y}), status_code=404)
    assert archive is not None
    return Response(data, media_type=archive.media_type, headers=_TILE_HEADERS)


@get("/dashboard/{name:str}", sync_to_thread=False, include_in_schema=False)
def dashboard_file(assets: DashboardAssets, name: str) -> Response[Any]:
    return assets.response(name)
