"""The command handler over the simulated flight controller, in virtual time.

Fast, deterministic checks of what the integration suite cannot easily provoke:
faults, offboard streams, flight-controller loss and the lag-tolerant event logic.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass

import msgspec
import pytest

from dronefleet.agent.fc_sim import SimFlightController
from dronefleet.agent.handler import CommandHandler, FlightSettings
from dronefleet.bus.clock import VirtualClock
from dronefleet.schemas import commands as c
from dronefleet.schemas.status import CommandStatus, SystemStatus
from dronefleet.sim.vehicle import Vehicle


@dataclass
class Rig:
    clock: VirtualClock
    vehicle: Vehicle
    handler: CommandHandler
    out: list[CommandStatus | SystemStatus]
    n: int = 0

    def send(self, cmd: c.Command) -> str:
        self.n += 1
        cmd = msgspec.structs.replace(cmd, command_id=f"c{self.n}")
        reply = self.handler.submit(cmd)
        assert reply.accepted, reply.reason
        return cmd.command_id

    def states(self, command_id: str) -> list[str]:
        return [s.state for s in self.out if isinstance(s, CommandStatus) and s.command_id == command_id]

    def system(self) -> list[str]:
        return [s.state for s in self.out if isinstance(s, SystemStatus)]

    async def run_until(self, predicate, limit_s: float = 120.0) -> None:
        waited = 0.0
        while not predicate():
            assert waited < limit_s, f"not reached in {limit_s} s virtual; statuses {self.out[-6:]}"
            await self.clock.advance(0.1)
            waited += 0.1


@pytest.fixture
async def rig() -> AsyncIterator[Rig]:
    clock = VirtualClock()
    vehicle = Vehicle(40.63349, -8.660815, 8.2)
    fc = SimFlightController(vehicle, clock)
    out: list[CommandStatus | SystemStatus] = []
    handler = CommandHandler("d1", fc, FlightSettings(), clock, out.append)
    await fc.start()
    task = asyncio.create_task(handler.run())
    r = Rig(clock, vehicle, handler, out)
    await clock.advance(0.1)
    yield r
    task.cancel()
    await asyncio.wait([task])
    await fc.close()


async def airborne(r: Rig, alt: float = 5) -> None:
    r.send(c.Arm())
    t = r.send(c.Takeoff(alt=alt))
    await r.run_until(lambda: "finish" in r.states(t))


async def test_connect_is_reported_at_start(rig: Rig) -> None:
    assert rig.system() == ["connect"]


async def test_manual_takeover_cancels_the_command_and_is_reported(rig: Rig) -> None:
    await airborne(rig)
    lat, lon = rig.vehicle.position().lat + 0.001, rig.vehicle.position().lon
    goto = rig.send(c.Goto(lat=lat, lon=lon))
    await rig.run_until(lambda: "start" in rig.states(goto))
    rig.vehicle.inject_manual(True)
    await rig.run_until(lambda: "start_manual" in rig.system())
    assert rig.states(goto) == ["start", "cancel"]
    cancel = [s for s in rig.out if isinstance(s, CommandStatus) and s.state == "cancel"][0]
    assert cancel.reason == "manual control"
    rig.vehicle.inject_manual(False)
    await rig.run_until(lambda: "stop_manual" in rig.system())


async def test_low_battery_return_is_a_system_event(rig: Rig) -> None:
    await airborne(rig)
    rig.vehicle.inject_battery(0.05)
    await rig.run_until(lambda: "return" in rig.system())
    await rig.run_until(lambda: "disarm" in rig.system())


async def test_commanded_return_and_disarm_are_not_system_events(rig: Rig) -> None:
    await airborne(rig)
    ret = rig.send(c.Return(alt=10))
    await rig.run_until(lambda: "finish" in rig.states(ret))
    await rig.run_until(lambda: not rig.vehicle.armed)
    await rig.clock.advance(1)
    # the automatic disarm after landing is reported, the return itself is not
    assert rig.system() == ["connect", "disarm"]


async def test_offboard_velocity_runs_until_stopped(rig: Rig) -> None:
    await airborne(rig)
    vel = rig.send(c.VelocityNed(north=2.0))
    await rig.run_until(lambda: rig.vehicle.mode == "offboard")
    await rig.clock.advance(3)
    assert rig.vehicle.vn == pytest.approx(2.0)
    assert rig.states(vel) == ["start"]
    stop = rig.send(c.StopOffboard())
    await rig.run_until(lambda: "success" in rig.states(stop))
    assert rig.states(vel) == ["start", "stop"]
    assert rig.vehicle.mode == "hold"
    assert "stop_offboard" not in rig.system()


async def test_position_ned_finishes_at_the_setpoint(rig: Rig) -> None:
    await airborne(rig)
    pos = rig.send(c.PositionNed(north=10.0, east=-5.0, down=-5.0))
    await rig.run_until(lambda: "finish" in rig.states(pos))
    assert (rig.vehicle.north, rig.vehicle.east) == pytest.approx((10.0, -5.0), abs=0.5)


async def test_a_setpoint_from_a_ground_flies_on_its_own_fields_only(rig: Rig) -> None:
    """What every command carries (its ground's epoch and id, its signature) is no
    setpoint value: a velocity from the active ground flies as one from anyone."""
    await airborne(rig)
    vel = rig.send(c.VelocityNed(north=2.0, ground_epoch=3, ground_id="alpha"))
    await rig.run_until(lambda: rig.vehicle.north > 5)
    assert rig.states(vel) == ["start"]


async def test_offboard_lost_by_the_autopilot_is_reported(rig: Rig) -> None:
    await airborne(rig)
    vel = rig.send(c.VelocityBody(forward=1.0))
    await rig.run_until(lambda: rig.vehicle.mode == "offboard")
    await rig.clock.advance(4)  # beyond the effect lag: the stream is ours, the drop is not
    rig.vehicle.hold()  # the autopilot leaves offboard on its own, as a failsafe would
    await rig.run_until(lambda: "stop" in rig.states(vel))
    assert rig.system() == ["connect", "stop_offboard"]


async def test_flight_controller_loss_and_return(rig: Rig) -> None:
    rig.vehicle.inject_link_loss(True)
    await rig.run_until(lambda: "disconnect" in rig.system())
    reply = rig.handler.submit(c.Arm(command_id="x"))
    assert not reply.accepted and reply.reason == "flight controller disconnected"
    rig.vehicle.inject_link_loss(False)
    await rig.run_until(lambda: rig.system().count("connect") == 2)


async def test_failed_takeoff_cancels_the_queued_goto(rig: Rig) -> None:
    rig.send(c.Arm())
    await rig.clock.advance(0.2)
    rig.vehicle.inject_manual(True)  # the vehicle will refuse the takeoff
    takeoff = rig.send(c.Takeoff(alt=5))
    goto = rig.send(c.Goto(lat=40.6336, lon=-8.6608))
    await rig.run_until(lambda: "failure" in rig.states(takeoff))
    assert rig.states(goto) == ["queued", "cancel"]


async def test_arm_then_takeoff_back_to_back_reach_the_autopilot_in_order(rig: Rig) -> None:
    arm = rig.send(c.Arm())
    takeoff = rig.send(c.Takeoff(alt=3))  # decided before the arm has executed
    await rig.run_until(lambda: "finish" in rig.states(takeoff))
    assert rig.states(arm) == ["success"]


async def test_a_command_sent_again_with_its_id_is_answered_as_before_and_run_once(rig: Rig) -> None:
    """A sender whose reply was lost on the radio retries with the same command id."""
    await airborne(rig)
    first = c.Goto(lat=40.6336, lon=-8.6608, alt=8.2 + 5, command_id="g1")
    assert rig.handler.submit(first).accepted
    await rig.clock.advance(0.5)
    again = rig.handler.submit(first)
    assert again.accepted and again.command_id == "g1"
    await rig.run_until(lambda: "finish" in rig.states("g1"))
    assert rig.states("g1") == ["start", "finish"]  # not superseded by itself, not run twice
