"""The simulated field on the emulated radio: drones' positions → link loss, live.

`RadioField` owns a RadioNet for the drones of a world and keeps its loss rules
following where the vehicles are (SPEC §8: updated `radio.update_hz` times a second,
5 by default), from the same RadioModel fast-time simulation uses. It also builds
the command lines that put a drone's agent and sensor programs inside the drone's
namespace: the agent connects to the ground's radio address and listens for its
on-board programs and neighbours on its own; the sensors connect to that agent. The
world's field sensors stand outside the radio (their own link to the ground). On a
secured mesh (the agents' `security.tls`, SPEC §9) every one of those links is
mutual TLS, and each sensor shows its drone's certificate (a field sensor its own).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Mapping
from pathlib import Path

from dronefleet.schemas.config_loading import Security
from dronefleet.schemas.endpoints import AGENT_PORT
from dronefleet.sim.agent_command import agent_command, sensor_command, world_file
from dronefleet.sim.radio import GROUND, Spot3, distance_3d, link_losses
from dronefleet.sim.radio_net import RadioNet
from dronefleet.sim.world import World

log = logging.getLogger(__name__)
RADIO_INTERFACE = "radio0"


class RadioField:
    def __init__(self, world: World, drone_ids: list[str], ground_port: int, security: Security | None = None) -> None:
        self.world = world
        self.ground_port = ground_port
        self.security = security or Security()
        self.scheme = "tls" if self.security.tls else "tcp"
        self.net = RadioNet(drone_ids, world.radio_model)
        self.ground = world.ground_spot3()
        self.losses: dict[tuple[str, str], int] = {}

    def up(self) -> RadioField:
        self.net.up()
        return self

    def close(self) -> None:
        self.net.close()

    @property
    def ground_endpoint(self) -> str:
        return f"{self.scheme}/{self.net.ground_address}:{self.ground_port}"

    def update(self, where: Mapping[str, Spot3]) -> None:
        """Apply the model to the drones' current positions (one nft transaction)."""
        nodes = {GROUND: self.ground, **where}
        self.losses = link_losses(self.world.radio_model, nodes)
        self.net.apply(self.losses)
        for drone_id, spot in where.items():
            self.net.shape(drone_id, distance_3d(spot, self.ground))

    async def follow(self, positions: Callable[[], Mapping[str, Spot3]]) -> None:
        period = 1.0 / self.world.radio_model.update_hz
        while True:
            self.update(positions())
            await asyncio.sleep(period)

    def agent_args(self, drone_id: str, fc: str, agent_config: Path | None = None, kind: str | None = None,
                   roles: list[str] | None = None) -> list[str]:
        return [*self.net.exec_args(drone_id), *agent_command(
            drone_id, fc, connect=[self.ground_endpoint], listen=[f"{self.scheme}/0.0.0.0:{AGENT_PORT}"],
            mesh_interface=RADIO_INTERFACE, config=agent_config, kind=kind, roles=roles or ())]

    def sensor_args(self, drone_id: str, kind: str, config_dir: Path) -> list[str]:
        """A simulated sensor program beside the drone's agent, in its namespace: any type
        the world reads (`fleet sensor simulate`; temperature from the heat field)."""
        return [*self.net.exec_args(drone_id), *sensor_command(
            world_file(self.world, config_dir), [f"{self.scheme}/127.0.0.1:{AGENT_PORT}"], self.security,
            drone_id=drone_id, kind=kind)]

    def field_sensor_args(self, sensor_id: str, config_dir: Path) -> list[str]:
        """A world's field sensor: on its own link to the ground (a pole's cable or modem,
        not the drones' radio), so outside the namespaces; on a secured mesh it shows the
        certificate issued for its id (`fleet pki issue ID --role sensor`)."""
        return sensor_command(world_file(self.world, config_dir), [self.ground_endpoint], self.security, field_id=sensor_id)

    def describe(self) -> list[str]:
        lines = [f"radio: {self.net.subnet}, ground {self.net.ground_address} (agents connect to {self.ground_endpoint}); "
                 f"loss 0 up to {self.world.radio_model.good_m:g} m, total from {self.world.radio_model.lost_m:g} m"]
        for drone_id in self.net.drone_ids:
            lines.append(f"radio: {drone_id} at {self.net.address(drone_id)} in namespace {self.net.netns(drone_id)}")
        return lines

