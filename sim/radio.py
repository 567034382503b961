"""The radio model (SPEC §8): the distance between two nodes → what their link does.

One model serves both emulations of the field network: fast-time simulation drops
messages on the in-process bus with it, and the namespace emulation (`radio_net.py`)
turns the same numbers into nftables drop rules on real packets. The defaults are
the thesis's measurement of its ad-hoc radio (§6.3.2): unstable from about 60 m,
the requested bitrate lost at about 80 m; here no loss up to `good_m`, rising
linearly to total loss at `lost_m`. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated

import msgspec
from msgspec import Meta

from dronefleet.schemas.geo import distance_m
from dronefleet.schemas.telemetry import GROUND_PEER, Position

GROUND = GROUND_PEER  # the node name of the field laptop in every link table
LOSS_STEPS = 1000  # loss is applied in 1/1000ths (nftables `numgen random mod 1000`)
# A hop losing this share of its packets still keeps a drone heard every 3 s; one losing
# twice that does not (`bench/relay_hop.py`, a static chain hovering 600 s: 24 of 24
# runs at 0 and 10 %, 9 of 12 over 3 s at 20 %).
HOLDING_LOSS = 0.1


class RadioModel(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """World file `radio:`; distances in metres along the straight line (3-D)."""

    good_m: Annotated[float, Meta(gt=0)] = 60.0  # no loss up to here
    lost_m: Annotated[float, Meta(gt=0)] = 100.0  # total loss from here on
    rate_kbit: Annotated[int, Meta(ge=0)] = 0  # link rate at short range (0 = not shaped)
    delay_ms: Annotated[float, Meta(ge=0)] = 2.0  # one-way delay at short range (where netem exists)
    update_hz: Annotated[float, Meta(ge=1, le=50)] = 5.0  # how often the emulation follows the drones

    def __post_init__(self) -> None:
        if self.lost_m <= self.good_m:
            raise ValueError("radio.lost_m must be greater than radio.good_m")

    def loss(self, distance_m: float) -> float:
        """Probability in [0, 1] that one packet (one message) is lost on one hop."""
        if distance_m <= self.good_m:
            return 0.0
        if distance_m >= self.lost_m:
            return 1.0
        return (distance_m - self.good_m) / (self.lost_m - self.good_m)

    def loss_steps(self, distance_m: float) -> int:
        """The loss in 1/1000ths, as the emulation applies it."""
        return round(self.loss(distance_m) * LOSS_STEPS)

    def rate(self, distance_m: float) -> int:
        """Link rate in kbit/s: full up to good_m, down to a tenth at lost_m (0 = unshaped)."""
        if not self.rate_kbit:
            return 0
        return max(1, round(self.rate_kbit * (1.0 - 0.9 * min(1.0, self.loss(distance_m)))))

    def delay(self, distance_m: float) -> float:
        """One-way delay in ms: grows tenfold across the unstable band (retries on air)."""
        return self.delay_ms * (1.0 + 9.0 * self.loss(distance_m))

    def usable(self, distance_m: float) -> bool:
        """Whether a link at this distance exists at all (the mesh may route over it)."""
        return distance_m < self.lost_m


class Spot3(msgspec.Struct, frozen=True):
    lat: float
    lon: float
    alt: float  # m AMSL


def spot_of(position: Position) -> Spot3:
    """Where a vehicle is, as the radio model sees it."""
    return Spot3(position.lat, position.lon, position.alt)


def distance_3d(a: Spot3, b: Spot3) -> float:
    flat = distance_m(a.lat, a.lon, b.lat, b.lon)
    return math.hypot(flat, a.alt - b.alt)


def link_losses(model: RadioModel, where: Mapping[str, Spot3]) -> dict[tuple[str, str], int]:
    """Loss in 1/1000ths for every unordered pair of nodes, keyed (a, b) with a < b."""
    names = sorted(where)
    return {
        (a, b): model.loss_steps(distance_3d(where[a], where[b]))
        for i, a in enumerate(names) for b in names[i + 1:]
    }
