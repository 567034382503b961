"""The body of every error the ground's HTTP API answers (SPEC §4): `{"error": "...",
"detail": ...}`, whoever raised it (a handler, Litestar's own validation, a route
that does not exist)."""

from __future__ import annotations

from typing import Any

import msgspec
from litestar import Response
from litestar.openapi.datastructures import ResponseSpec


class ApiError(msgspec.Struct, frozen=True, kw_only=True):
    error: str
    detail: Any = None


REASONS = {
    400: "malformed request (the field at fault is named; for a script: line and column)",
    404: "no such drone, field sensor, mission or route",
    409: "the drone cannot run this command now, or the mission already ended (reason given)",
    413: "the script is too large",
    502: "the agent answered with an error",
    504: "the drone's agent did not answer (unreachable)",
}


def error_specs(*codes: int) -> dict[int, ResponseSpec]:
    """The OpenAPI responses of these error statuses, each an ApiError."""
    return {c: ResponseSpec(ApiError, description=REASONS[c], generate_examples=False) for c in codes}


def error_response(status: int, error: str, detail: Any = None) -> Response[ApiError]:
    return Response(ApiError(error=error, detail=detail), status_code=status)
