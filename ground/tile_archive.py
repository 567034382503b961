"""Map tiles from one file, for a field with no internet (issue 54): a PMTiles archive
(Protomaps' single-file format, read and written with the `pmtiles` library).

`dashboard.tiles` may name such a file; the ground then serves its tiles at
`/tiles/{z}/{x}/{y}` and the dashboard draws them, scaling the deepest it holds when
zoomed in further. `fleet tiles fetch` makes one while a connection exists.
"""

from __future__ import annotations

import mmap
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pmtiles.reader import MemorySource, Reader
from pmtiles.tile import Compression, TileType, zxy_to_tileid
from pmtiles.writer import Writer

MEDIA_TYPES = {TileType.PNG: "image/png", TileType.JPEG: "image/jpeg", TileType.WEBP: "image/webp",
               TileType.AVIF: "image/avif"}


class TileArchiveError(Exception):
    """The file is not a readable PMTiles archive of raster tiles (the message says why)."""


class TileArchive:
    """A PMTiles archive opened for reading; `close()` when done."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._file = open(self.path, "rb")  # noqa: SIM115 - kept open with its map until close()
        except OSError as exc:
            raise TileArchiveError(f"{path}: {exc.strerror}") from None
        try:
            self._map = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
            self._reader = Reader(MemorySource(self._map))  # our own map, so close() can release it
            self.header: dict[str, Any] = self._reader.header()
            self.metadata: dict[str, Any] = self._reader.metadata()
        except Exception as exc:  # a short, empty or foreign file: pmtiles raises what it meets
            self._file.close()
            raise TileArchiveError(f"{path}: not a PMTiles archive ({exc})") from None
        tile_type = self.header.get("tile_type")
        if tile_type not in MEDIA_TYPES:
            self.close()
            raise TileArchiveError(f"{path}: holds {getattr(tile_type, 'name', tile_type)} tiles; the map draws raster "
                                   "tiles (PNG, JPEG, WebP, AVIF)")
        self.media_type = MEDIA_TYPES[tile_type]

    def tile(self, z: int, x: int, y: int) -> bytes | None:
        """The tile's bytes, or None where the archive holds none."""
        if not (self.min_zoom <= z <= self.max_zoom):
            return None
        data: bytes | None = self._reader.get(z, x, y)
        return data

    @property
    def min_zoom(self) -> int:
        return int(self.header["min_zoom"])

    @property
    def max_zoom(self) -> int:
        return int(self.header["max_zoom"])

    @property
    def attribution(self) -> str:
        return str(self.metadata.get("attribution", ""))

    def summary(self) -> dict[str, Any]:
        """What `fleet tiles info` prints: zooms, bounds (S, W, N, E), tiles, attribution."""
        h = self.header
        return {
            "file": str(self.path), "tiles": int(h["addressed_tiles_count"]), "media_type": self.media_type,
            "min_zoom": self.min_zoom, "max_zoom": self.max_zoom,
            "bounds": [h["min_lat_e7"] / 1e7, h["min_lon_e7"] / 1e7, h["max_lat_e7"] / 1e7, h["max_lon_e7"] / 1e7],
            "attribution": self.attribution, "source": self.metadata.get("source", ""),
            "bytes": self.path.stat().st_size,
        }

    def close(self) -> None:
        self._map.close()
        self._file.close()


def tile_type_of(data: bytes) -> TileType:
    """PNG, JPEG or WebP, from the first bytes."""
    if data.startswith(b"\x89PNG"):
        return TileType.PNG
    if data.startswith(b"\xff\xd8"):
        return TileType.JPEG
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return TileType.WEBP
    raise TileArchiveError("a tile that is neither PNG, JPEG nor WebP")


def write_archive(path: Path, tiles: Iterable[tuple[int, int, int, bytes]], bounds: tuple[float, float, float, float],
                  metadata: dict[str, Any]) -> int:
    """Write `tiles` (z, x, y, bytes; one image type) as a PMTiles archive at `path`,
    whole or not at all (written beside it, then renamed). `bounds` are S, W, N, E.
    Returns how many tiles it holds."""
    listed = list(tiles)
    if not listed:
        raise TileArchiveError("no tiles to write")
    entries = sorted(((zxy_to_tileid(z, x, y), data) for z, x, y, data in listed), key=lambda e: e[0])
    zooms = [z for z, _, _, _ in listed]
    south, west, north, east = bounds
    scratch = path.with_name(path.name + ".writing")
    with open(scratch, "wb") as f:
        writer = Writer(f)
        for tile_id, data in entries:
            writer.write_tile(tile_id, data)
        writer.finalize({
            "tile_type": tile_type_of(entries[0][1]), "tile_compression": Compression.NONE,
            "min_lon_e7": round(west * 1e7), "min_lat_e7": round(south * 1e7),
            "max_lon_e7": round(east * 1e7), "max_lat_e7": round(north * 1e7),
            "center_zoom": (min(zooms) + max(zooms)) // 2,
            "center_lon_e7": round((west + east) / 2 * 1e7), "center_lat_e7": round((south + north) / 2 * 1e7),
        }, metadata)
    scratch.replace(path)
    return len(entries)

