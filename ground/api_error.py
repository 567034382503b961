"""The body of every error the ground's HTTP API answers (SPEC §4): `{"error": "...",
"detail": ...}`, whoever raised it (a handler, Litestar's own validation, a route
that does not exist)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgspec
from litestar import Response
from litestar.openapi.datastructures import ResponseSpec
from litestar.openapi.spec import OpenAPIMediaType, Operation, RequestBody


class ApiError(msgspec.Struct, frozen=True, kw_only=True):
    error: str
    detail: Any = None


REASONS = {
    400: "malformed request (the field at fault is named; for a script: line and column)",
    403: "an observer ground, which never commands (SPEC §14: the body names the active ground and its API), "
         "or an API token whose role may not do this",
    404: "no such drone, field sensor, mission or route",
    409: "the drone cannot run this command now, or the mission already ended (reason given)",
    413: "the script is too large",
    422: "the mission's preflight (fast time against the live fleet) failed, naming line, simulated time and cause; or it could not run",
    502: "the agent answered with an error",
    503: "a standby ground (SPEC §14: the body names the active ground and its API), or the ground is busy with "
         "another simulation, or a simulation ran out of time",
    504: "the drone's agent did not answer (unreachable)",
}


def error_specs(*codes: int) -> dict[int, ResponseSpec]:
    """The OpenAPI responses of these error statuses, each an ApiError."""
    return {c: ResponseSpec(ApiError, description=REASONS[c], generate_examples=False) for c in codes}


def error_response(status: int, error: str, detail: Any = None) -> Response[ApiError]:
    return Response(ApiError(error=error, detail=detail), status_code=status)


class ApiFailure(Exception):
    """Raised by a handler typed for its success: the app answers it as `ApiError` with
    `status` (its exception handler, `failure_response`)."""

    def __init__(self, status: int, error: str, detail: Any = None, headers: dict[str, str] | None = None) -> None:
        super().__init__(error)
        self.status, self.error, self.detail, self.headers = status, error, detail, headers or {}


def failure_response(request: Any, failure: ApiFailure) -> Response[ApiError]:
    response = error_response(failure.status, failure.error, failure.detail)
    response.headers.update(failure.headers)
    return response


def body_operation(media_type: str, schema: dict[str, Any], description: str) -> type[Operation]:
    """An operation whose handler reads its body itself (to name the field at fault, or
    take text): what the body is, for the schema."""

    @dataclass
    class _BodyOperation(Operation):
        def __post_init__(self) -> None:
            self.request_body = RequestBody(
                content={media_type: OpenAPIMediaType(schema=schema)},  # type: ignore[arg-type]
                required=True, description=description,
            )
    return _BodyOperation


def text_operation(description: str) -> type[Operation]:
    """An operation whose body is text (not JSON), as the schema should say."""
    return body_operation("text/plain", {"type": "string"}, description)


def json_operation(kind: type, description: str) -> type[Operation]:
    """An operation whose body is the msgspec struct `kind` as JSON (its schema inlined)."""
    full = msgspec.json.schema(kind)
    defs = full.pop("$defs", {})

    def inline(node: Any) -> Any:
        if isinstance(node, dict):
            if "$ref" in node:
                return inline(defs[node["$ref"].rsplit("/", 1)[1]])
            return {k: inline(v) for k, v in node.items()}
        if isinstance(node, list):
            return [inline(v) for v in node]
        return node

    return body_operation("application/json", inline(full), description)
