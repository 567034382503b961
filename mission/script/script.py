"""ScriptMission: a mission whose main subroutine is a mission script (SPEC §5), run on
the life cycle of mission.lifecycle.Mission. It holds what only the script's verbs and
plugins use: the compiled script and its seed, the drone views the script was given
(plugins monitor them) and the plugins enabled in this mission."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from dronefleet.bus.clock import Clock
from dronefleet.mission.lifecycle.fleet_port import FleetPort
from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.lifecycle.record import MissionLogLine, MissionRecord
from dronefleet.mission.script.drone import Drone
from dronefleet.mission.script.dsl import build_namespace
from dronefleet.mission.script.host import ScriptHost
from dronefleet.mission.script.plugins import MissionPlugins, PluginLibrary
from dronefleet.mission.script.sandbox import Guards


class ScriptMission(ScriptHost):
    def __init__(
        self,
        record: MissionRecord,
        code: Any,
        station: FleetPort,
        clock: Clock,
        *,
        deterministic: bool = False,
        seed: int | None = None,
        on_change: Callable[[Mission], None] = lambda m: None,
        on_log: Callable[[Mission, MissionLogLine], None] = lambda m, line: None,
        plugins: PluginLibrary | None = None,
        enable: dict[str, dict[str, Any]] | None = None,
    ) -> None:
        super().__init__(record, station, clock, deterministic=deterministic, on_change=on_change, on_log=on_log)
        self.code = code
        self.seed = seed
        self._wrappers: list[Drone] = []
        self.plugins: MissionPlugins = MissionPlugins(self, plugins)
        self._enable_first = enable or {}

    def script_main(self) -> Callable[[], None]:
        """The script on its sandboxed globals, after the plugins enabled from outside
        (`fleet mission simulate --enable`) are enabled as its first lines would."""
        assert self.scheduler is not None
        guards = Guards(self.scheduler.tick, lambda text: self.log("info", text), self.seed)
        namespace = build_namespace(self, guards)

        def main() -> None:
            for plugin_id, inputs in self._enable_first.items():
                namespace["enable"](plugin_id, **inputs)
            exec(self.code, namespace)  # noqa: S102 - compiled by the sandbox

        return main

    def add_wrapper(self, wrapper: Drone) -> None:
        """A drone newly assigned by the script: plugins start monitoring it."""
        self._wrappers.append(wrapper)
        self.plugins.drone_added(wrapper)

    def drop_wrapper(self, wrapper: Drone) -> None:
        """A drone the script revoked: its monitors stop."""
        if wrapper in self._wrappers:
            self._wrappers.remove(wrapper)
        self.plugins.drone_removed(wrapper)

    def wrappers(self) -> list[Drone]:
        return [w for w in self._wrappers if w.id in self.requests]
