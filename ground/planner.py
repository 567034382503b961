"""The ground's planner: the slots its predictions run in (the preflight's and the
dashboard's), and the world a prediction flies in, made from the live fleet. The
routes (ground/plan_routes.py) and the preflight (ground/preflight.py) both use it;
the prediction itself is ground/planning.py's."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

from dronefleet.ground.planning import live_world
from dronefleet.ground.station import GroundStation
from dronefleet.sim.world import World


class Planner:
    """Slots for predictions (preflights and the planner's simulations), each a child
    process taking a core for seconds: up to `slots` side by side, the next refused
    (503) rather than queued behind a slow one."""

    def __init__(self, slots: int = 2) -> None:
        self.slots = slots
        self.running = 0

    def free(self) -> bool:
        return self.running < self.slots

    @contextlib.asynccontextmanager
    async def slot(self) -> AsyncIterator[None]:
        self.running += 1
        try:
            yield
        finally:
            self.running -= 1


def plugins_dir(station: GroundStation) -> Path | None:
    """The ground's own plugins (besides the bundled ones), for a prediction to load too."""
    path = station.config.plugins_path.expanduser()
    return path if path.is_dir() else None


def live_world_of(station: GroundStation) -> World:
    """The world of a prediction: the fleet as the ground knows it now."""
    reg = station.registry
    gs = station.config.dashboard.ground_station
    readings = [r for d in reg.ids() for r in reg.sensor_readings(d)] + reg.field.readings()
    field_sensors = [info for i in reg.field.ids() if (info := reg.field.get(i)) is not None]
    return live_world([(reg.info(d), reg.telemetry(d)) for d in reg.ids()], station.config.geofence,
                      (gs.lat, gs.lon) if gs is not None else None, station.config.mission.flight_drain_per_s,
                      readings, field_sensors)
