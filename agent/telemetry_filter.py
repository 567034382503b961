"""The telemetry filter: from a flight-controller snapshot to the published Telemetry.

MAVSDK offers twenty-odd fields; the wire carries the SPEC §2 set, with the health
checks folded into a list of failures and the velocity's norm as `speed`.
"""

from __future__ import annotations

import math

from dronefleet.agent.fc_port import FcState
from dronefleet.schemas.telemetry import Telemetry


def to_telemetry(drone_id: str, seq: int, timestamp_ms: int, s: FcState) -> Telemetry:
    v = s.velocity
    return Telemetry(
        drone_id=drone_id,
        timestamp=timestamp_ms,
        seq=seq,
        armed=s.armed,
        battery=s.battery,
        flight_mode=s.flight_mode,  # type: ignore[arg-type]
        gps_info=s.gps_info,
        heading=round(s.heading, 3),
        health_failures=list(s.health_failures),  # type: ignore[arg-type]
        home=s.home,
        landed_state=s.landed_state,  # type: ignore[arg-type]
        position=s.position,
        velocity=v,
        speed=round(math.sqrt(v.north**2 + v.east**2 + v.down**2), 3),
    )
