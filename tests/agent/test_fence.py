"""The geofence as pure geometry (SPEC §11): targets, straight paths, the ceiling."""

from __future__ import annotations

import msgspec
import pytest

from dronefleet.schemas.fence import Geofence
from dronefleet.schemas.geo import destination

BASE = (40.634125, -8.660336)


def at(north_m: float, east_m: float) -> tuple[float, float]:
    lat, _ = destination(*BASE, north_m, 0.0) if north_m >= 0 else destination(*BASE, -north_m, 180.0)
    _, lon = destination(*BASE, east_m, 90.0) if east_m >= 0 else destination(*BASE, -east_m, 270.0)
    return lat, lon


# An L: 100 m x 100 m with the north-east quarter cut away (a concave corner at 50, 50).
L_SHAPE = Geofence(polygon=[at(0, 0), at(100, 0), at(100, 50), at(50, 50), at(50, 100), at(0, 100)], max_alt_m=60)


@pytest.mark.parametrize(("start", "end", "alt", "refused"), [
    ((10, 10), (40, 80), 20, None),  # inside to inside
    ((10, 10), (120, 10), 20, "is outside the fence"),  # target beyond the north edge
    ((90, 30), (30, 90), 20, "path to the target leaves"),  # both inside, the line cuts the missing corner
    ((80, 20), (20, 80), 20, None),  # touching the concave corner only: on the border
    ((10, 10), (40, 80), 61, "over max_alt_m 60"),  # the ceiling, above home
    ((10, 10), (0, 50), 20, None),  # onto the border: inside
    ((-30, 20), (20, 20), 20, None),  # a drone outside may fly back in
    ((-30, 20), (20, 20 + 200), 20, "is outside the fence"),
    ((120, 20), (30, 80), 20, "path to the target leaves"),  # in from the north, out through the cut corner and back in
])
def test_a_flight_is_judged_on_its_target_and_its_straight_path(start: tuple[float, float], end: tuple[float, float],
                                                                 alt: float, refused: str | None) -> None:
    why = L_SHAPE.check(at(*start), at(*end), alt)
    if refused is None:
        assert why is None, why
    else:
        assert why is not None and why.startswith("geofence: ") and refused in why, why


def test_a_drone_is_found_outside_by_its_position_and_the_ceiling_with_a_margin() -> None:
    assert L_SHAPE.outside(*at(80, 80), 10) is not None  # in the cut corner
    assert L_SHAPE.outside(*at(10, 10), 61) is None  # 1 m over: an overshoot, not outside
    assert L_SHAPE.outside(*at(10, 10), 63) is not None
    assert Geofence().outside(*at(1000, 1000), 500) is None and not Geofence().limits


@pytest.mark.parametrize(("polygon", "message"), [
    ([[40.6, -8.6], [40.7, -8.6]], "at least 3 vertices"),
    ([[40.6, -8.6], [40.7, -8.6], [40.8, -8.6]], "encloses no area"),
    ([[40.6, -8.6], [40.7, -8.6], [95.0, -8.6]], "Expected `float` <= 90"),
])
def test_a_bad_fence_is_refused_with_its_reason(polygon: list[list[float]], message: str) -> None:
    with pytest.raises(msgspec.ValidationError, match=message):
        msgspec.convert({"polygon": polygon}, Geofence)
