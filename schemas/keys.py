"""Key expressions of the Zenoh wire contract (SPEC §2), built in one place.

Every key is `[<namespace>/]drone/<id>/<kind>` (or `ground/…`, `sensor/…`). Nothing
else in the code base concatenates key strings: ask a `Keys` for them, and use
`Keys.parse` to go back from a received key to (drone id, kind).
"""

from __future__ import annotations

import re

import msgspec

from dronefleet.schemas.errors import InvalidMessage

# Zenoh reserves these in key chunks; an id containing one would address other drones.
_ID = re.compile(r"^[A-Za-z0-9_.\-]+$")


def check_id(value: str, what: str = "drone id") -> str:
    if not _ID.match(value or ""):
        raise InvalidMessage(
            f"{what} {value!r} is not usable in a key: use letters, digits, '_', '-' or '.'",
            field=what,
        )
    return value


class DroneKey(msgspec.Struct, frozen=True):
    drone_id: str
    kind: str  # telem | status | cmd | bundle | link | ping | alive | about | sensor
    rest: str = ""  # sensor type for `sensor/<type>`


class Keys(msgspec.Struct, frozen=True):
    namespace: str = ""

    def _k(self, *parts: str) -> str:
        return "/".join(p for p in (self.namespace, *parts) if p)

    def telem(self, drone_id: str = "*") -> str:
        return self._k("drone", drone_id, "telem")

    def status(self, drone_id: str = "*") -> str:
        return self._k("drone", drone_id, "status")

    def cmd(self, drone_id: str) -> str:
        return self._k("drone", drone_id, "cmd")

    def bundle(self, drone_id: str) -> str:
        return self._k("drone", drone_id, "bundle")

    def link(self, drone_id: str = "*") -> str:
        return self._k("drone", drone_id, "link")

    def ping(self, drone_id: str) -> str:
        return self._k("drone", drone_id, "ping")

    def alive(self, drone_id: str = "*") -> str:
        return self._k("drone", drone_id, "alive")

    def about(self, drone_id: str = "*") -> str:
        return self._k("drone", drone_id, "about")

    def sensor(self, drone_id: str = "*", sensor_type: str = "*") -> str:
        return self._k("drone", drone_id, "sensor", sensor_type)

    def drone(self, drone_id: str = "*") -> str:
        """Everything one drone (or every drone, by default) publishes."""
        return self._k("drone", drone_id, "**")

    def field_sensor(self, sensor_id: str = "*", sensor_type: str = "*") -> str:
        return self._k("sensor", sensor_id, sensor_type)

    def field_sensor_alive(self, sensor_id: str = "*") -> str:
        return self._k("sensor", sensor_id, "alive")

    def parse_field_sensor(self, key: str) -> tuple[str, str] | None:
        """(sensor id, type) of a `sensor/<id>/<type>` key under this namespace, else None."""
        prefix = f"{self.namespace}/" if self.namespace else ""
        if not key.startswith(prefix):
            return None
        parts = key[len(prefix):].split("/")
        if len(parts) != 3 or parts[0] != "sensor" or not parts[1] or not parts[2]:
            return None
        return parts[1], parts[2]

    def ground(self, *parts: str) -> str:
        """`ground/…`: what the ground itself says (recordings: its log, its missions)."""
        return self._k("ground", *parts)

    def ground_alive(self) -> str:
        return self._k("ground", "alive")

    def ground_ping(self) -> str:
        return self._k("ground", "ping")

    def everything(self) -> str:
        return self._k("**")

    def parse(self, key: str) -> DroneKey | None:
        """(drone id, kind) of a `drone/…` key under this namespace, else None."""
        prefix = f"{self.namespace}/" if self.namespace else ""
        if not key.startswith(prefix):
            return None
        parts = key[len(prefix):].split("/")
        if len(parts) < 3 or parts[0] != "drone":
            return None
        return DroneKey(parts[1], parts[2], "/".join(parts[3:]))
