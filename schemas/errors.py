"""The root of every error Fleet raises, and the branch for bad messages.

Errors a user sees name what is at fault (a field, a drone, a file) so the message
alone says what to fix. Third-party exceptions are translated into these at the
boundary where they occur.
"""

from __future__ import annotations


class FleetError(Exception):
    """Root of all Fleet errors. `exit_code` is what the CLI exits with when one
    reaches it: 1 a runtime failure, 2 bad usage or configuration."""

    exit_code = 1


class InvalidMessage(FleetError):
    """A payload that does not decode into the schema of its key family.

    `field` is the JSON path of the offending field (``$.lat``) when known.
    """

    def __init__(self, reason: str, field: str | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.field = field


class ConfigError(FleetError):
    """A configuration file or flag that cannot be used; the message names the key."""

    exit_code = 2


STATE_UNKNOWN = "unknown"  # the code of the ground's 409 for a drone it has not heard lately


class CommandRejected(FleetError):
    """The ground or the agent will not run a command now; `status` is the HTTP code."""

    def __init__(self, status: int, reason: str, code: str | None = None, other: str | None = None) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason
        self.code = code  # machine-readable kind of a 409: "geofence", "conflict", "unknown"
        self.other = other  # the other drone of a conflict
