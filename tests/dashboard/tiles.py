"""A tile server for the map tests: solid-colour PNG tiles (encoded here, no imaging
library) at the zooms a test asks for, counting the requests."""

from __future__ import annotations

import http.server
import math
import re
import struct
import threading
import zlib
from typing import Any


def png(rgb: tuple[int, int, int], size: int = 256) -> bytes:
    """A plain square PNG (no imaging library needed)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\x00" + bytes(rgb) * size for _ in range(size))
    header = struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


class TileServer:
    """`dashboard.tiles` on 127.0.0.1: a checkerboard of plain tiles, and which were asked for."""

    def __init__(self, zooms: range = range(0, 20)) -> None:
        """Tiles at `zooms` only (public servers stop at 19; a field server may hold 15-18):
        elsewhere 404. A faulty server: `answers[(z, x, y)]` lists the statuses that tile
        gets first (then 200), and after `serve_at_most` tiles every answer is 503."""
        self.requested: list[tuple[int, int, int]] = []
        self.answers: dict[tuple[int, int, int], list[int]] = {}
        self.serve_at_most: int | None = None
        self.served = 0
        tiles = {0: png((222, 226, 214)), 1: png((206, 214, 196))}
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - the http.server name
                found = re.fullmatch(r"/(\d+)/(\d+)/(\d+)\.png", self.path)
                if not found:
                    self.send_error(404)
                    return
                z, x, y = (int(g) for g in found.groups())
                server.requested.append((z, x, y))
                if z not in zooms:
                    self.send_error(404)
                    return
                first = server.answers.get((z, x, y))
                if first:
                    self.send_error(first.pop(0))
                    return
                if server.serve_at_most is not None and server.served >= server.serve_at_most:
                    self.send_error(503)
                    return
                server.served += 1
                body = tiles[(x + y) % 2]
                self.send_response(200)
                self.send_header("Content-Type", "image/png")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.template = f"http://127.0.0.1:{self.httpd.server_address[1]}/{{z}}/{{x}}/{{y}}.png"
        self.thread = threading.Thread(target=self.httpd.serve_forever, name="tile server", daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(10)


def tile_of(lat: float, lon: float, z: int) -> tuple[int, int, int]:
    """The web mercator tile holding (lat, lon) at zoom z."""
    n = 2**z
    y = (1 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2
    return z, int((lon + 180) / 360 * n), int(y * n)
