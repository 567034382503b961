"""A world's field drawn as map tiles (issue 54): what the dashboard shows under the
drones when no tile server or archive is at hand, as `fleet demo` does and
`fleet tiles render WORLD` writes.

There is no imagery in a world file, so the map draws what the world knows, on a plain
ground colour: its heat sources (a warm disc, darker towards the centre, and the ring
where the field reaches `ring_temp_c`: the perimeter the demo's mission traces), the
areas of its other fields (gas, …) as tinted discs, and faint lines every `GRID_M`
metres north and east of the laptop, so distances read off the map at any zoom.

Each tile is computed from where its pixels are (web mercator, `mercantile` for the
tile maths), so neighbouring tiles and zooms join without seams. `numpy` does the
pixels and matplotlib writes the PNG (both come with the `plots` extra).
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterator, Sequence
from typing import Any

from dronefleet.schemas.geo import EARTH_RADIUS_M, Box
from dronefleet.sim.world import World

TILE_PX = 256
GRID_M = 50.0  # a faint line every this many metres north and east of the laptop
MARGIN_M = 250.0  # the map reaches this far beyond every drone, source and the laptop (a first view)
DEFAULT_ZOOMS = range(15, 20)  # 15: the whole field in a tile or two; 19: ~0.3 m a pixel
GROUND_RGB = (0.87, 0.90, 0.82)
HEAT_RGB = (0.96, 0.52, 0.16)
RING_RGB = (0.62, 0.10, 0.05)
FIELD_RGB = (0.55, 0.45, 0.80)
GRID_RGB = (0.62, 0.66, 0.58)
EARTH_M_PER_DEG = math.radians(1.0) * EARTH_RADIUS_M  # the sphere schemas/geo.py measures on (the heat field's)


def world_box(world: World, margin_m: float = MARGIN_M) -> Box:
    """Everything the world places (drones, the laptop, sources, field sensors), with
    `margin_m` around it."""
    spots: list[tuple[float, float]] = [(d.lat, d.lon) for d in world.spawn() if d.lat is not None and d.lon is not None]
    spots += [(s.lat, s.lon) for s in world.heat_sources]
    spots += [(s.lat, s.lon) for s in world.field_sensors]
    spots += [(src.lat, src.lon) for models in world.fields.values() for m in models.values() for src in m.sources]
    ground = world.ground_spot()
    spots.append((ground.lat, ground.lon))
    lat0 = ground.lat
    dlat = margin_m / EARTH_M_PER_DEG
    dlon = margin_m / (EARTH_M_PER_DEG * math.cos(math.radians(lat0)))
    return Box(south=min(a for a, _ in spots) - dlat, west=min(o for _, o in spots) - dlon,
               north=max(a for a, _ in spots) + dlat, east=max(o for _, o in spots) + dlon)


def render(world: World, zooms: Sequence[int] = DEFAULT_ZOOMS, box: Box | None = None,
           ring_temp_c: float = 40.0) -> Iterator[tuple[int, int, int, bytes]]:
    """(z, x, y, PNG bytes) for every tile of `box` (the world's, by default) at `zooms`."""
    import mercantile

    box = box or world_box(world)
    for tile in mercantile.tiles(box.west, box.south, box.east, box.north, list(zooms)):
        yield tile.z, tile.x, tile.y, _png(_pixels(world, tile, ring_temp_c))


def _pixels(world: World, tile: Any, ring_temp_c: float) -> Any:
    import mercantile
    import numpy as np

    # Pixel centres in web mercator metres, then degrees (mercator is linear in x and y).
    left, bottom, right, top = mercantile.xy_bounds(tile)
    step = (right - left) / TILE_PX
    xs = left + (np.arange(TILE_PX) + 0.5) * step
    ys = top - (np.arange(TILE_PX) + 0.5) * step
    lon = np.degrees(xs / 6_378_137.0)
    lat = np.degrees(2 * np.arctan(np.exp(ys / 6_378_137.0)) - math.pi / 2)
    ground = world.ground_spot()
    per_lon = EARTH_M_PER_DEG * math.cos(math.radians(ground.lat))
    east = (lon - ground.lon)[np.newaxis, :] * per_lon
    north = (lat - ground.lat)[:, np.newaxis] * EARTH_M_PER_DEG
    metres_per_px = step * math.cos(math.radians(ground.lat))

    rgb = np.empty((TILE_PX, TILE_PX, 3))
    rgb[:] = GROUND_RGB

    def metres_from(lat_deg: float, lon_deg: float) -> Any:
        return np.hypot(east - (lon_deg - ground.lon) * per_lon, north - (lat_deg - ground.lat) * EARTH_M_PER_DEG)

    def tint(colour: tuple[float, float, float], weight: Any) -> None:
        w = np.clip(weight, 0.0, 1.0)[..., np.newaxis]
        rgb[:] = rgb * (1 - w) + np.asarray(colour) * w

    for models in world.fields.values():
        for model in models.values():
            for src in model.sources:
                tint(FIELD_RGB, 0.35 * (1 - metres_from(src.lat, src.lon) / src.radius))
    temperature = np.full((TILE_PX, TILE_PX), world.environment_temp)
    for s in world.heat_sources:
        share = np.clip(1 - metres_from(s.lat, s.lon) / s.radius, 0.0, 1.0)
        temperature = np.maximum(temperature, world.environment_temp + (s.temp - world.environment_temp) * share)
        tint(HEAT_RGB, np.where(share > 0, 0.25 + 0.6 * share, 0.0))
    if world.heat_sources:
        # the ring: where the field crosses ring_temp_c, about 1.5 pixels wide at any zoom
        gradient = max((s.temp - world.environment_temp) / s.radius for s in world.heat_sources)
        near = np.abs(temperature - ring_temp_c) < gradient * max(metres_per_px, 0.05) * 0.75
        rgb[near] = RING_RGB
    for coordinate in (east, north):
        offset = np.abs((coordinate + GRID_M / 2) % GRID_M - GRID_M / 2)
        line = np.broadcast_to(offset < max(metres_per_px * 0.6, 0.02), (TILE_PX, TILE_PX))
        rgb[line] = rgb[line] * 0.4 + np.asarray(GRID_RGB) * 0.6
    return rgb


def _png(rgb: Any) -> bytes:
    from matplotlib import image

    out = io.BytesIO()
    image.imsave(out, rgb, format="png")
    return out.getvalue()
