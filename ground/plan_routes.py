"""Planning on the map (SPEC §10): `POST /mission/check`, `POST /mission/simulate` and
`POST /mission/plan/export` — what the dashboard's planner asks as a plan changes,
before anything flies (ground/planning.py does the work)."""

from __future__ import annotations

from typing import Any

from litestar import Request, Response, post

from dronefleet.ground.api_error import ApiFailure, error_response, error_specs, json_operation, text_operation
from dronefleet.ground.planner import Planner, live_world_of, plugins_dir
from dronefleet.ground.planning import (
    Bounds,
    ExportBody,
    Prediction,
    SimulateBody,
    SimulationBound,
    decode_body,
    predict,
)
from dronefleet.ground.station import GroundStation
from dronefleet.mission.hosting.manager import MissionManager
from dronefleet.mission.script.checks import check_script, first_problem
from dronefleet.mission.script.qgc_plan import Waypoint, export_plan
from dronefleet.mission.script.sandbox import ScriptError
from dronefleet.schemas.errors import InvalidMessage

MAX_BODY_BYTES = 256 * 1024


def plugin_verbs(missions: MissionManager) -> frozenset[str]:
    return missions.plugins.verbs() if missions.plugins is not None else frozenset()


async def _body(request: Request[Any, Any, Any]) -> bytes | Response[Any]:
    body = await request.body()
    if len(body) > MAX_BODY_BYTES:
        return error_response(413, f"the body is {len(body)} bytes; the limit is {MAX_BODY_BYTES}")
    return body


@post("/mission/check", status_code=200, responses=error_specs(413),
      operation_class=text_operation("A mission script (Python DSL, SPEC §5), as text."),
      summary="Check a mission script without running it: every syntax, sandbox, name, call and unit problem "
              "with its line and column")
async def check_mission_script(missions: MissionManager, request: Request[Any, Any, Any]) -> Response[Any]:
    body = await _body(request)
    if not isinstance(body, bytes):
        return body
    source = body.decode("utf-8", "replace")
    problems = [p.detail() for p in check_script(source, plugin_verbs=plugin_verbs(missions))]
    return Response({"ok": not problems, "problems": problems})


@post("/mission/simulate", status_code=200, responses=error_specs(400, 413, 503),
      operation_class=json_operation(SimulateBody, "The script and how much simulated time it may take (s)."),
      summary="Fly a script in fast time against the live fleet (positions, batteries, fence); nothing flies")
async def simulate_mission(station: GroundStation, planner: Planner, missions: MissionManager,
                           request: Request[Any, Any, Any]) -> Response[Prediction]:
    body = await _body(request)
    if not isinstance(body, bytes):
        return body
    try:
        wanted: SimulateBody = decode_body(body, SimulateBody, "simulate")
        first_problem(wanted.source, plugin_verbs=plugin_verbs(missions))
        world = live_world_of(station)
    except ScriptError as exc:
        raise ApiFailure(400, str(exc), exc.detail()) from None
    except InvalidMessage as exc:
        raise ApiFailure(400, exc.reason, {"field": exc.field}) from None
    if not planner.free():
        raise ApiFailure(503, f"{planner.slots} simulations are running on the ground; try again when one ends")
    async with planner.slot():
        try:
            bounds = Bounds(memory_mb=station.config.mission.max_memory_mb)
            return Response(await predict(wanted.source, world, wanted.max_s, plugins_dir(station), bounds))
        except (SimulationBound, InvalidMessage) as exc:
            raise ApiFailure(503, str(exc)) from None


@post("/mission/plan/export", status_code=200, responses=error_specs(400, 413),
      operation_class=json_operation(ExportBody, "Waypoints (alt: m above home), home [lat, lon, alt AMSL], takeoff altitude, end."),
      summary="Waypoints (as the planner has them) as a QGroundControl plan: mission version 2, SimpleItems, frame 3")
async def export_mission_plan(station: GroundStation, request: Request[Any, Any, Any]) -> Response[Any]:
    body = await _body(request)
    if not isinstance(body, bytes):
        return body
    try:
        wanted: ExportBody = decode_body(body, ExportBody, "export")
    except InvalidMessage as exc:
        return error_response(400, exc.reason, {"field": exc.field})
    fence = station.config.geofence.polygon if station.config.geofence is not None else None
    plan = export_plan([Waypoint(w.lat, w.lon, w.alt, w.hold_s, w.speed) for w in wanted.waypoints],
                       (wanted.home[0], wanted.home[1], wanted.home[2]), wanted.takeoff_alt, wanted.end,
                       [list(v) for v in fence] if fence else None)
    return Response(plan, headers={"Content-Disposition": 'attachment; filename="fleet.plan"'})
