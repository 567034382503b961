"""What a mission script's verbs and plugins need of the mission that runs them.

`ScriptHost` is the mission life cycle (`mission.lifecycle.Mission`) and what only a
script adds to it: the drone views the script was given and the switch of the plugins
enabled in it. The verbs (`dsl.Verbs`) and the plugins (`plugins.MissionPlugins`) are
written against it; `script.ScriptMission` serves it. Neither module imports the other's
mission, so the script layer has one direction: host < dsl, plugins < script.
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any, Protocol

from dronefleet.mission.lifecycle.mission import Mission
from dronefleet.mission.script.drone import Drone


class PluginSwitch(Protocol):
    """The plugins a mission enabled, as its verbs switch them."""

    def enable(self, plugin_id: str, inputs: dict[str, Any], base: dict[str, Any], mission_names: dict[str, Any]) -> None: ...

    def disable(self, plugin_id: str, mission_names: dict[str, Any]) -> None: ...


class ScriptHost(Mission):
    """A mission whose main subroutine is a script: the life cycle, and the script's drones
    and plugins."""

    plugins: PluginSwitch

    @abstractmethod
    def add_wrapper(self, wrapper: Drone) -> None:
        """A drone newly assigned by the script: plugins start monitoring it."""

    @abstractmethod
    def drop_wrapper(self, wrapper: Drone) -> None:
        """A drone the script revoked: its monitors stop."""

    @abstractmethod
    def wrappers(self) -> list[Drone]:
        """The script's drone views still assigned."""
