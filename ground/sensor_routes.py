"""`GET /sensor` and `GET /sensor/{id}`: the field sensors the ground hears (SPEC §2,
sensors that are not on a drone), with their position, liveliness and latest readings."""

from __future__ import annotations

from typing import Annotated

from litestar import Response, get
from litestar.openapi.spec import Example
from litestar.params import Parameter

from dronefleet.ground.api_error import ApiFailure, error_specs
from dronefleet.ground.field_sensor_registry import FieldSensorInfo
from dronefleet.ground.station import GroundStation


@get("/sensor", sync_to_thread=False, summary="Field sensors heard (not on a drone), with their latest readings")
def list_field_sensors(
    station: GroundStation,
    sensor_type: Annotated[str | None, Parameter(query="type", description="only sensors publishing this type",
                                                 examples=[Example(value="gas")])] = None,
) -> list[FieldSensorInfo]:
    table = station.registry.field
    found = [table.get(i) for i in table.ids()]
    return [s for s in found if s is not None and (sensor_type is None or sensor_type in s.types)]


@get("/sensor/{sensor_id:str}", sync_to_thread=False, summary="One field sensor", responses=error_specs(404))
def show_field_sensor(station: GroundStation, sensor_id: str) -> Response[FieldSensorInfo]:
    found = station.registry.field.get(sensor_id)
    if found is None:
        raise ApiFailure(404, f"no field sensor {sensor_id!r} is heard", {"sensor_id": sensor_id})
    return Response(found)
