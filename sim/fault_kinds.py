"""The faults a simulated world can play (`faults:` in a world file, `fleet sim fault KIND`)."""

from __future__ import annotations

from typing import Literal

FaultKind = Literal[
    "rc_takeover", "rc_release", "low_battery", "link_pull", "link_restore",
    "health_failure", "health_ok", "gps_loss", "gps_ok", "gust", "arm_denied", "arm_ok",
]
