"""The body of every error the ground's HTTP API answers (SPEC §4): `{"error": "...",
"detail": ...}`, whoever raised it (a handler, Litestar's own validation, a route
that does not exist)."""

from __future__ import annotations

from typing import Any

import msgspec


class ApiError(msgspec.Struct, frozen=True, kw_only=True):
    error: str
    detail: Any = None
