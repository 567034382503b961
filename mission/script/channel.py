"""`channel`: named values shared by a mission's subroutines (SPEC §5); reading a name
not yet written waits until some subroutine writes it."""

from __future__ import annotations

import asyncio
from typing import Any

from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.script.activity import waiting_on_channel
from dronefleet.mission.script.drone import call


class Channel:
    """`channel.name = v` binds once; reading `channel.name` blocks until bound."""

    def __init__(self, mission: Mission) -> None:
        object.__setattr__(self, "_m", mission)
        object.__setattr__(self, "_values", {})
        object.__setattr__(self, "_waiters", {})

    def __setattr__(self, name: str, value: Any) -> None:
        values: dict[str, Any] = object.__getattribute__(self, "_values")
        if name in values:
            if values[name] == value:
                return
            raise ValueError(f"channel.{name} is already bound to {values[name]!r}")
        values[name] = value
        waiters: dict[str, list[Any]] = object.__getattribute__(self, "_waiters")
        for fut in waiters.pop(name, []):
            if not fut.done():
                fut.set_result(value)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        values: dict[str, Any] = object.__getattribute__(self, "_values")
        if name in values:
            return values[name]
        waiting_on_channel(object.__getattribute__(self, "_m"), name)
        fut = asyncio.get_running_loop().create_future()
        object.__getattribute__(self, "_waiters").setdefault(name, []).append(fut)
        return call(object.__getattribute__(self, "_m"), fut)
