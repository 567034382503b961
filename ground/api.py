"""The ground's HTTP API (SPEC §4) on Litestar: drones, commands, logs, live events.

Handlers are thin: they read the GroundStation and translate its answers and errors
into HTTP. Every error, including Litestar's own (bad query parameter, unknown
route, wrong method), answers `{"error": "...", "detail": ...}`. The command body is
decoded by the schemas' own decoder (so a 400 names the field exactly as an agent
would) while the OpenAPI document still describes it as the Command union.

`GET /` serves the web dashboard (SPEC §10), routed by ground/dashboard_routes.py.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import AsyncIterator, Awaitable
from typing import Annotated, Any, Literal

import msgspec
from litestar import Litestar, MediaType, Request, Response, delete, get, post
from litestar.datastructures import ResponseHeader
from litestar.di import Provide
from litestar.exceptions import HTTPException, ValidationException
from litestar.openapi import OpenAPIConfig
from litestar.openapi.spec import Components, SecurityScheme
from litestar.params import Parameter
from litestar.response import ServerSentEvent, ServerSentEventMessage

from dronefleet.bus.port import QueryRefused, Unreachable
from dronefleet.ground.api_error import ApiError, ApiFailure, body_operation, failure_response, text_operation
from dronefleet.ground.api_error import error_response as _error
from dronefleet.ground.api_error import error_specs as _errors
from dronefleet.ground.config import ROLE_RANK, ApiToken
from dronefleet.ground.dashboard_routes import (
    DashboardAssets,
    TileSource,
    dashboard_config,
    dashboard_file,
    index,
    map_tile,
)
from dronefleet.ground.describe import Level
from dronefleet.ground.eventlog import format_line
from dronefleet.ground.plan_routes import check_mission_script, export_mission_plan, plugin_verbs, simulate_mission
from dronefleet.ground.planner import Planner
from dronefleet.ground.preflight import Preflight, PreflightBusy, PreflightUnavailable, run_preflight
from dronefleet.ground.sensor_routes import list_field_sensors, show_field_sensor
from dronefleet.ground.station import GroundStation
from dronefleet.ground.tile_archive import TileArchive
from dronefleet.mission.hosting.manager import MissionEnded, MissionManager, UnknownMission
from dronefleet.mission.lifecycle.record import Activity, MissionLogLine, MissionRecord
from dronefleet.mission.script.checks import first_problem
from dronefleet.mission.script.plugins import PluginListing
from dronefleet.mission.script.qgc_plan import NotAPlan, import_plan
from dronefleet.mission.script.sandbox import ScriptError
from dronefleet.schemas.bundles import BundleRecord, BundleReply, TaskBundle
from dronefleet.schemas.commands import Command, CommandReply
from dronefleet.schemas.errors import CommandRejected, InvalidMessage
from dronefleet.schemas.fleet import DroneInfo, DroneState, WatchEvent
from dronefleet.schemas.grounds import NotCommanding
from dronefleet.schemas.telemetry import SensorReading, Telemetry

log = logging.getLogger(__name__)
KEEPALIVE_S = 15.0
LOG_CURSOR = "Fleet-Log-Cursor"

DataParam = Literal["telem", "info", "sensors"]
EventKind = Literal["telemetry", "status", "drone", "log", "mission", "mission_log", "field_sensor", "subroutine"]
MAX_SCRIPT_BYTES = 1_000_000


class DroneView(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """One drone; `data=` keeps only the named part."""

    info: DroneInfo | None = None
    telem: Telemetry | None = None
    sensors: list[SensorReading] | None = None


class MissionCreated(msgspec.Struct, frozen=True, kw_only=True):
    mission_id: str
    preflight: Preflight | None = None  # what the preflight predicted; None when skipped


class PlanImported(msgspec.Struct, frozen=True, kw_only=True):
    """A QGroundControl plan as a mission script (SPEC §13), as `fleet mission import` makes it."""

    script: str
    left_out: list[str]  # "item N: why", one per item (or fence part) not carried over
    geofence: dict[str, Any] | None  # the plan's inclusion polygon in the ground's `geofence:` form
    # the same plan as the dashboard's planner edits it (waypoints with alt above home)
    waypoints: list[dict[str, Any]] = []
    takeoff_alt: float | None = None
    end: str = "hold"


class MissionView(MissionRecord, kw_only=True):
    """A mission record with its log lines (GET /mission/{id})."""

    log: list[MissionLogLine] = msgspec.field(default_factory=list)
    source: str | None = None  # the script
    subroutines: list[Activity] = msgspec.field(default_factory=list)  # what each last did (/events `subroutine`)
    marks: list[Activity] = msgspec.field(default_factory=list)  # its plugins' actions, oldest first


# ---- command body: decoded by schemas/, documented as the Command union --------------


def _command_body_schema() -> tuple[dict[str, Any], dict[str, Any]]:
    """OpenAPI schema of the POST body: each Command without drone_id/timestamp."""
    (schema,), components = msgspec.json.schema_components((Command,), ref_template="#/components/schemas/{name}")
    for component in components.values():
        props = component.get("properties", {})
        for name in ("drone_id", "timestamp"):
            props.pop(name, None)
    return {"oneOf": schema.pop("anyOf"), **schema}, components


_BODY_SCHEMA, _BODY_COMPONENTS = _command_body_schema()


def _bundle_body_schema() -> dict[str, Any]:
    schema = msgspec.json.schema(TaskBundle)
    body = schema["$defs"]["TaskBundle"] if "$defs" in schema else schema
    for name in ("drone_id", "timestamp"):
        body["properties"].pop(name, None)
    body["required"] = ["steps"]
    return body


_BUNDLE_SCHEMA = _bundle_body_schema()


_CommandOperation = body_operation("application/json", _BODY_SCHEMA, "A command (SPEC §2) without drone_id and timestamp; the ground adds them and a command_id if absent.")


# ---- handlers ---------------------------------------------------------------------


def _view(station: GroundStation, drone_id: str, data: DataParam | None) -> DroneView:
    reg = station.registry
    return DroneView(
        info=reg.info(drone_id) if data in (None, "info") else None,
        telem=reg.telemetry(drone_id) if data in (None, "telem") else None,
        sensors=reg.sensor_readings(drone_id) if data in (None, "sensors") else None,
    )


@get("/drone", sync_to_thread=False, responses=_errors(400), summary="All drones matching the filters")
def list_drones(
    station: GroundStation,
    state_filter: Annotated[DroneState | None, Parameter(query="state", description="only drones in this state")] = None,
    sensors: Annotated[list[str] | None, Parameter(description="only drones carrying all these sensor types")] = None,
    data_part: Annotated[DataParam | None, Parameter(query="data", description="keep only this part")] = None,
) -> list[DroneView]:
    return [_view(station, i, data_part) for i in station.registry.select(state_filter, sensors)]


@get(
    "/drone/logs", sync_to_thread=False, media_type=MediaType.TEXT, responses=_errors(400),
    response_headers=[ResponseHeader(
        name=LOG_CURSOR, value="0", documentation_only=True,
        description="id of the last line returned (or `after` when none): pass it as `after` to get only newer lines",
    )],
    summary="The event log as text lines, oldest first",
)
def drone_logs(
    station: GroundStation,
    drone_id: list[str] | None = None,
    loglevel: list[Level] | None = None,
    after: Annotated[int, Parameter(ge=0, le=2**62, description="only lines after this cursor")] = 0,
    limit: Annotated[int | None, Parameter(ge=1, le=100_000)] = None,
) -> Response[str]:
    rows = station.events.query(drone_id or (), loglevel or (), after_id=after, limit=limit)
    text = "".join(format_line(line) + "\n" for _, line in rows)
    cursor = rows[-1][0] if rows else after
    return Response(text, media_type=MediaType.TEXT, headers={LOG_CURSOR: str(cursor)})


@get("/drone/{drone_id:str}", sync_to_thread=False, responses=_errors(400, 404), summary="One drone")
def show_drone(
    station: GroundStation,
    drone_id: str,
    data_part: Annotated[DataParam | None, Parameter(query="data", description="keep only this part")] = None,
) -> Response[DroneView]:
    if drone_id not in station.registry:
        raise ApiFailure(404, f"no drone {drone_id!r} is registered", {"drone_id": drone_id})
    return Response(_view(station, drone_id, data_part))


@post(
    "/drone/{drone_id:str}/cmd", status_code=200, operation_class=_CommandOperation,
    responses=_errors(400, 403, 404, 409, 502, 503, 504), summary="Send a command; 200 when the agent accepted it",
)
async def send_command(station: GroundStation, drone_id: str, request: Request[Any, Any, Any]) -> Response[CommandReply]:
    return await _to_drone(drone_id, station.command(drone_id, await request.body(), who=_who(request)))


def _not_commanding(request: Any, refused: NotCommanding) -> Response[Any]:
    """SPEC §14: everything stays visible; only the active ground commands. The refusal
    names the active ground and where its API answers (the app's handler of it)."""
    return Response(refused.refusal, status_code=refused.refusal.status)


async def _to_drone(drone_id: str, sending: Awaitable[Any]) -> Response[Any]:
    """One request to a drone's agent, its failures as the API's errors."""
    try:
        reply = await sending
    except InvalidMessage as exc:
        field = exc.field.removeprefix("$.") if exc.field else None
        return _error(400, str(exc), {"field": field})
    except NotCommanding:  # the app's handler answers it
        raise
    except CommandRejected as exc:
        detail: dict[str, Any] = {"drone_id": drone_id}
        if exc.code is not None:  # SPEC §11: "geofence" or "conflict" (with the other drone)
            detail["reason"] = exc.code
        if exc.other is not None:
            detail["other"] = exc.other
        return _error(exc.status, exc.reason, detail)
    except QueryRefused as exc:
        return _error(502, f"the agent of {drone_id} answered with an error: {exc}", {"drone_id": drone_id})
    except Unreachable as exc:
        return _error(504, f"{drone_id} did not answer: {exc}", {"drone_id": drone_id})
    return Response(reply)


_BundleOperation = body_operation("application/json", _BUNDLE_SCHEMA, "A task bundle (SPEC §6) without drone_id and timestamp; the ground adds them and a bundle_id if absent.")


@post(
    "/drone/{drone_id:str}/bundle", status_code=200, operation_class=_BundleOperation,
    responses=_errors(400, 403, 404, 409, 502, 503, 504), summary="Send a task bundle; 200 when the agent accepted it",
)
async def push_bundle(station: GroundStation, drone_id: str, request: Request[Any, Any, Any]) -> Response[BundleReply]:
    return await _to_drone(drone_id, station.push(drone_id, await request.body(), who=_who(request)))


@get(
    "/drone/{drone_id:str}/bundle/{bundle_id:str}", responses=_errors(404, 502, 504),
    summary="What the drone did with a bundle, asked of the drone itself",
)
async def show_bundle(station: GroundStation, drone_id: str, bundle_id: str) -> Response[BundleRecord]:
    return await _to_drone(drone_id, station.bundle_record(drone_id, bundle_id))


# ---- missions ---------------------------------------------------------------------


async def _text(request: Request[Any, Any, Any], what: str, detail: dict[str, Any] | None = None) -> str | Response[Any]:
    """The body as text, or the 413/400 saying why not."""
    body = await request.body()
    if len(body) > MAX_SCRIPT_BYTES:
        return _error(413, f"the {what} is {len(body)} bytes; the limit is {MAX_SCRIPT_BYTES}")
    try:
        return body.decode("utf-8")
    except UnicodeDecodeError as exc:
        return _error(400, f"the {what} is not UTF-8 text: {exc}", detail)


@post(
    "/mission", status_code=201, operation_class=text_operation("The mission script (Python DSL, SPEC §5), as text."),
    responses=_errors(400, 403, 413, 422, 503),
    summary="Submit a mission script; 201 with its id and its preflight, 400 with line/column when its text is wrong, "
            "422 when its preflight (fast time against the live fleet) fails or cannot run",
)
async def submit_mission(
    missions: MissionManager,
    station: GroundStation,
    planner: Planner,
    request: Request[Any, Any, Any],
    name: Annotated[str, Parameter(max_length=200, description="a label for lists")] = "",
    preflight: Annotated[bool, Parameter(description="fly it in fast time against the live fleet first (false: "
                                                     "skip on purpose, logged)")] = True,
) -> Response[MissionCreated]:
    missions.check_commanding()  # before its text is read or its preflight flown
    source = await _text(request, "script", {"line": None, "column": None})
    if not isinstance(source, str):
        return source
    verbs = plugin_verbs(missions)
    try:
        first_problem(source, plugin_verbs=verbs)
    except ScriptError as exc:
        raise ApiFailure(400, str(exc), exc.detail()) from None
    report = None
    if preflight and station.config.mission.preflight:
        try:
            report = await run_preflight(station, planner, source)
        except PreflightBusy as busy:
            wait_s = math.ceil(busy.retry_after_s)
            raise ApiFailure(503, f"the ground is running {planner.slots} preflights (mission.preflight_concurrency); "
                                  f"try again in {wait_s} s, or submit with --no-preflight / ?preflight=false",
                             {"retry_after_s": wait_s}, headers={"Retry-After": str(wait_s)}) from None
        except PreflightUnavailable as exc:
            raise ApiFailure(422, f"preflight could not run: {exc} (submit with --no-preflight / ?preflight=false "
                                  "to fly it anyway)") from None
        if not report.passed:
            raise ApiFailure(422, report.failure(), msgspec.to_builtins(report))
    try:
        record = missions.submit(source, name, submitted_by=_who(request),
                                 notes=[report.summary()] if report is not None else None)
    except ScriptError as exc:
        raise ApiFailure(400, str(exc), exc.detail()) from None
    if not preflight:
        station.log_ground("warn", f"Mission {record.mission_id} submitted without its preflight"
                                   + (f" by {_who(request)}" if _who(request) else ""))
    return Response(MissionCreated(mission_id=record.mission_id, preflight=report), status_code=201)


@post(
    "/mission/plan", status_code=200,
    operation_class=text_operation("A QGroundControl plan (JSON, `fileType: Plan`, mission version 2), as text."),
    responses=_errors(400, 413),
    summary="A QGroundControl plan as a mission script (nothing is submitted); 400 when it is not such a plan",
)
async def import_mission_plan(
    request: Request[Any, Any, Any],
    drone: Annotated[str, Parameter(max_length=200, description="the drone the script assigns (default: any free one)")] = "",
) -> Response[PlanImported]:
    text = await _text(request, "plan")
    if not isinstance(text, str):
        return text
    try:
        imported = import_plan(text, drone or None, "the uploaded plan")
    except NotAPlan as exc:
        raise ApiFailure(400, str(exc)) from None
    return Response(PlanImported(script=imported.script, left_out=imported.left_out, geofence=imported.geofence,
                                 waypoints=imported.waypoints, takeoff_alt=imported.takeoff_alt, end=imported.end))


@get("/mission", sync_to_thread=False, summary="Every mission record, oldest first")
def list_missions(missions: MissionManager) -> list[MissionRecord]:
    return missions.list()


@get("/mission/{mission_id:str}", sync_to_thread=False, responses=_errors(404), summary="One mission record and its log")
def show_mission(missions: MissionManager, mission_id: str) -> Response[MissionView]:
    try:
        record = missions.get(mission_id)
        lines = missions.log(mission_id)
    except UnknownMission:
        raise ApiFailure(404, f"no mission {mission_id!r}", {"mission_id": mission_id}) from None
    lanes = missions.lanes(mission_id)
    return Response(MissionView(**msgspec.structs.asdict(record), log=lines, source=missions.store.source(mission_id),
                                subroutines=list(lanes.subroutines.values()), marks=lanes.marks))


@delete(
    "/mission/{mission_id:str}", status_code=200, responses=_errors(403, 404, 409, 503),
    summary="Cancel a running mission (cause user)",
)
async def cancel_mission(missions: MissionManager, mission_id: str, request: Request[Any, Any, Any]) -> Response[MissionRecord]:
    who = _who(request)
    try:
        record = missions.cancel(mission_id, message=f"cancelled by {who}" if who else None)
    except UnknownMission:
        raise ApiFailure(404, f"no mission {mission_id!r}", {"mission_id": mission_id}) from None
    except MissionEnded as exc:
        raise ApiFailure(409, str(exc), {"mission_id": mission_id}) from None
    return Response(record, status_code=200)


@get(
    "/events", sync_to_thread=False, media_type="text/event-stream", responses=_errors(400),
    summary="Live server-sent events: telemetry (rate-capped per drone), status, drone (registry changes), log",
)
def events(station: GroundStation, types: list[EventKind] | None = None) -> ServerSentEvent:
    wanted: set[str] = set(types or ("telemetry", "status", "drone", "log", "mission", "mission_log", "subroutine"))
    return ServerSentEvent(_stream(station, wanted))


async def _stream(station: GroundStation, wanted: set[str]) -> AsyncIterator[ServerSentEventMessage]:
    with station.watch() as watcher:
        # First the current picture, so a dashboard needs no separate GET to start.
        for drone_id in station.registry.ids():
            if "drone" in wanted:
                yield _message(WatchEvent("drone", station.registry.info(drone_id)))
        while True:
            try:
                async with asyncio.timeout(KEEPALIVE_S):
                    event = await watcher.queue.get()
            except TimeoutError:
                yield ServerSentEventMessage(comment="keepalive")
                continue
            if event.kind == "end":
                return
            if event.kind in wanted:
                yield _message(event)


def _message(event: WatchEvent) -> ServerSentEventMessage:
    data = event.data
    if event.kind == "log":
        data = {**msgspec.to_builtins(data), "text": format_line(data)}
    return ServerSentEventMessage(
        event=event.kind, data=msgspec.json.encode(data).decode(), id=str(event.id) if event.id is not None else None
    )


@get("/ground", sync_to_thread=False, summary="The grounds heard on the mesh, their roles and epochs (SPEC §14)")
def list_grounds(station: GroundStation) -> list[dict[str, Any]]:
    return station.peers.listing()


@get(
    "/ground/{ground_id:str}/log", sync_to_thread=False, media_type=MediaType.TEXT, responses=_errors(400, 404),
    summary="Another ground's event log as this ground keeps a copy of it (SPEC §14), oldest first",
)
def ground_log(
    station: GroundStation, ground_id: str,
    after: Annotated[int, Parameter(ge=0, le=2**62, description="only lines after this one")] = 0,
) -> Response[Any]:
    if ground_id not in station.events.origins():
        return Response(ApiError(error=f"no copy of ground {ground_id!r}'s log here", detail={"ground_id": ground_id}),
                        status_code=404, media_type=MediaType.JSON)
    rows = station.events.copies(ground_id, after_seq=after)
    return Response("".join(format_line(line) + "\n" for _, line in rows), media_type=MediaType.TEXT,
                    headers={LOG_CURSOR: str(rows[-1][0] if rows else after)})


@get("/ground/{ground_id:str}/mission", sync_to_thread=False,
     summary="Another ground's missions as this ground keeps a copy of them (SPEC §14)")
def ground_missions(missions: MissionManager, ground_id: str) -> list[MissionRecord]:
    return missions.store.copied_records(ground_id)


@get("/ground/{ground_id:str}/mission/{mission_id:str}", sync_to_thread=False, responses=_errors(404),
     summary="One of another ground's missions and its log, as copied here (SPEC §14)")
def ground_mission(missions: MissionManager, ground_id: str, mission_id: str) -> Response[Any]:
    record = next((r for r in missions.store.copied_records(ground_id) if r.mission_id == mission_id), None)
    if record is None:
        return _error(404, f"no copy of mission {mission_id!r} of ground {ground_id!r} here",
                      {"ground_id": ground_id, "mission_id": mission_id})
    return Response({**msgspec.to_builtins(record), "log": msgspec.to_builtins(missions.store.copied_log(ground_id, mission_id))})


@get("/plugin", sync_to_thread=False, summary="Loaded plugins with their inputs, and plugin files that failed to load")
def list_plugins(missions: MissionManager) -> PluginListing:
    return missions.plugins.describe() if missions.plugins is not None else PluginListing(plugins=[], errors=[])


@get("/openapi.json", sync_to_thread=False, include_in_schema=False, media_type="application/vnd.oai.openapi+json")
def openapi_json(request: Request[Any, Any, Any]) -> bytes:
    return msgspec.json.encode(request.app.openapi_schema.to_schema())


# ---- errors -----------------------------------------------------------------------


# Python names of query parameters whose wire name is a Litestar reserved word.
_QUERY_ALIASES = {"data_part": "data", "state_filter": "state"}


def _http_error(request: Request[Any, Any, Any], exc: HTTPException) -> Response[ApiError]:
    error, detail = str(exc.detail), None
    if isinstance(exc, ValidationException) and isinstance(exc.extra, list) and exc.extra:
        detail = [
            {**item, "key": _QUERY_ALIASES.get(str(item.get("key")), item.get("key"))} if isinstance(item, dict) else item
            for item in exc.extra
        ]
        error = "; ".join(f"{d.get('key')}: {d.get('message')}" for d in detail if isinstance(d, dict)) or error
    response = _error(exc.status_code, error, detail)
    if exc.headers:
        response.headers.update(exc.headers)
    return response


def _internal_error(request: Request[Any, Any, Any], exc: Exception) -> Response[ApiError]:
    log.exception("%s %s failed", request.method, request.url.path)
    return _error(500, f"internal error: {type(exc).__name__}")


def _add_command_components(app: Litestar) -> None:
    # Litestar rebuilds components from its own registry, so the body's are added after.
    schemas = app.openapi_schema.components.schemas
    assert schemas is not None
    for name, schema in _BODY_COMPONENTS.items():
        schemas.setdefault(name, schema)


# ---- who may use the API (SPEC §9) --------------------------------------------------

def _public(path: str) -> bool:
    """The page and its files are code, not data: served to anyone. Everything else
    (its config.json included) needs a token once any is configured."""
    return path == "/" or (path.startswith("/dashboard/") and path != "/dashboard/config.json")


def _who(request: Request[Any, Any, Any]) -> str | None:
    """The name of the token holder who sent this request (None: tokens are off)."""
    return getattr(request.state, "who", None)


def _authorize(tokens: list[ApiToken]) -> Any:
    by_token = {t.token: t for t in tokens}

    async def authorize(request: Request[Any, Any, Any]) -> Response[ApiError] | None:
        path = request.url.path
        if not by_token or _public(path):
            return None
        scheme, _, presented = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() != "bearer":  # an EventSource cannot set headers: ?access_token=
            presented = request.query_params.get("access_token", "")
        token = by_token.get(presented.strip())
        if token is None:
            response = _error(401, "a valid API token is needed: Authorization: Bearer <token> (api.tokens)",
                              {"scheme": "bearer"})
            response.headers["WWW-Authenticate"] = "Bearer"
            return response
        needed = "viewer" if request.method in ("GET", "HEAD", "OPTIONS") else "operator"
        if ROLE_RANK[token.role] < ROLE_RANK[needed]:
            return _error(403, f"{token.name} is a {token.role}: {request.method} {path} needs the {needed} role",
                          {"role": token.role, "needed": needed})
        request.state.who = token.name
        return None

    return authorize


def create_app(station: GroundStation, missions: MissionManager, tiles: TileArchive | None = None) -> Litestar:
    """The HTTP API and the dashboard; `tiles`: the archive `dashboard.tiles` names, opened."""
    assets = DashboardAssets.load()
    tile_source = TileSource(tiles)
    planner = Planner(station.config.mission.preflight_concurrency)
    tokens = station.config.api.all_tokens()
    return Litestar(
        [
            list_drones, drone_logs, show_drone, send_command, push_bundle, show_bundle, submit_mission, list_missions, show_mission, list_plugins,
            import_mission_plan, list_field_sensors, show_field_sensor, check_mission_script, simulate_mission, export_mission_plan,
            cancel_mission, events, index, openapi_json, dashboard_config, dashboard_file, map_tile, list_grounds, ground_log, ground_missions, ground_mission,
        ],
        dependencies={
            "station": Provide(lambda: station, sync_to_thread=False),
            "missions": Provide(lambda: missions, sync_to_thread=False),
            "assets": Provide(lambda: assets, sync_to_thread=False),
            "tile_source": Provide(lambda: tile_source, sync_to_thread=False),
            "planner": Provide(lambda: planner, sync_to_thread=False),
        },
        exception_handlers={ApiFailure: failure_response, NotCommanding: _not_commanding, HTTPException: _http_error, Exception: _internal_error},
        openapi_config=OpenAPIConfig(
            title="Fleet ground station", version="0.1.0",
            components=Components(security_schemes={"bearer": SecurityScheme(
                type="http", scheme="bearer", description="api.tokens: viewer (GET), operator (commands, missions), admin")}),
            security=[{"bearer": []}] if tokens else None,
        ),
        before_request=_authorize(tokens),
        on_startup=[_add_command_components],
        debug=False,
        logging_config=None,  # the CLI configures logging, not the framework
    )
