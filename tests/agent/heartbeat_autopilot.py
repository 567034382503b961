"""A flight-controller seam for the arming properties: an autopilot whose state changes
at once when commanded (or on its own) and whose *reported* state follows only at its
heartbeats, as PX4 and ArduCopter report arming and mode (once a second, at a phase of
their own). It keeps a log of what it did and what it reported, for the properties to
judge the agent by. Fast time only: it sleeps on a VirtualClock."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from dronefleet.agent.fc_port import Changes, FcRejected, FcState, Listener
from dronefleet.bus.clock import VirtualClock
from dronefleet.schemas.geo import destination, distance_m
from dronefleet.schemas.telemetry import Home, Position

SPAWN = (40.63349, -8.660815, 8.2)
CLIMB_S = 4.0  # a takeoff's climb, a landing's descent, a leg's flight
LAND_DISARM_S = 2.0  # COM_DISARM_LAND: disarmed this long after touchdown
PREFLIGHT_DISARM_S = 10.0  # COM_DISARM_PRFLT: disarmed this long after an arming with no takeoff
TICK_S = 0.05


@dataclass(frozen=True)
class Report:
    t: float
    state: FcState


@dataclass
class HeartbeatAutopilot:
    clock: VirtualClock
    heartbeat_s: float = 1.0
    phase_s: float = 0.0
    # What it is (changes at once)
    armed: bool = False
    mode: str = "hold"
    landed: str = "on_ground"
    lat: float = SPAWN[0]
    lon: float = SPAWN[1]
    rel_alt: float = 0.0
    home: Home = field(default_factory=lambda: Home(lat=SPAWN[0], lon=SPAWN[1], alt=SPAWN[2]))
    # The log: every report sent, and when each disarm happened and why
    reports: list[Report] = field(default_factory=list)
    disarms: list[tuple[float, str]] = field(default_factory=list)  # (t, "command" | "auto")
    _reported: FcState = field(default_factory=FcState)
    _changes: Changes = field(default_factory=Changes)
    _task: asyncio.Task[None] | None = None
    _touchdown: float | None = None
    _until: float | None = None  # when the climb, descent or leg under way ends
    _target: tuple[float, float, float] | None = None
    _takeoff_alt: float = 5.0
    _armed_at: float | None = None  # an arming not followed by a takeoff yet

    # ----- the port ---------------------------------------------------------------------

    @property
    def make(self) -> str | None:
        return "px4"  # its heartbeat lag is PX4's

    async def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run())

    def state(self) -> FcState:
        return self._reported

    def watch(self, listener: Listener) -> None:
        self._changes.watch(listener)

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()

    async def arm(self) -> None:
        if self.armed:
            return  # accepted, nothing changes: PX4 answers an arm of an armed drone so
        if self.mode in ("land", "return_to_launch"):
            raise FcRejected(f"arm: denied in {self.mode}")
        self.armed, self.home = True, Home(lat=self.lat, lon=self.lon, alt=SPAWN[2])
        self._touchdown, self._armed_at = None, self.now

    async def disarm(self) -> None:
        if self.landed != "on_ground":
            raise FcRejected("disarm: denied in air")
        self._disarm("command")

    async def takeoff(self, alt_m: float) -> None:
        self.mode, self._takeoff_alt = "takeoff", alt_m  # PX4 takes a takeoff while disarmed, and waits on the ground
        if self.armed:
            self._fly(alt_m)

    async def land(self) -> None:
        if self.landed == "on_ground":
            return
        self.mode, self._target, self._until = "land", None, self.now + CLIMB_S

    async def goto(self, lat: float, lon: float, alt_amsl: float, yaw_deg: float | None, speed_mps: float | None) -> None:
        if not self.armed or self.landed == "on_ground":
            raise FcRejected("goto: denied")
        self.mode, self._target, self._until = "hold", (lat, lon, alt_amsl - SPAWN[2]), self.now + CLIMB_S

    async def return_to_launch(self, alt_m: float) -> None:
        if not self.armed or self.landed == "on_ground":
            return
        self.mode, self._target, self._until = "return_to_launch", (self.home.lat, self.home.lon, 0.0), self.now + CLIMB_S

    async def hold(self) -> None:
        self.mode, self._target, self._until = "hold", None, None

    async def start_offboard(self) -> None:
        raise FcRejected("start offboard: not modelled")

    async def stop_offboard(self) -> None:
        raise FcRejected("stop offboard: not modelled")

    async def set_setpoint(self, kind: str, values: dict[str, float | None]) -> None:
        raise FcRejected(f"{kind}: not modelled")

    async def upload_fence(self, polygon: list[tuple[float, float]]) -> None:
        pass

    # ----- what it does on its own ------------------------------------------------------

    @property
    def now(self) -> float:
        return self.clock.monotonic()

    def failsafe_return(self) -> None:
        """A failsafe of the autopilot's own: RTL (in the air)."""
        if self.armed and self.landed == "in_air":
            self.mode, self._target, self._until = "return_to_launch", (self.home.lat, self.home.lon, 0.0), self.now + CLIMB_S

    def _fly(self, alt_m: float) -> None:
        self.landed, self._touchdown, self._armed_at = "in_air", None, None
        self._target, self._until = (self.lat, self.lon, alt_m), self.now + CLIMB_S

    def _disarm(self, why: str) -> None:
        self.armed, self._touchdown, self._armed_at = False, None, None
        if self.mode in ("land", "takeoff"):
            self.mode = "hold"
        self.disarms.append((self.now, why))

    def _step(self) -> None:
        now = self.now
        if self.mode == "takeoff" and self.armed and self.landed == "on_ground":
            self._fly(self._takeoff_alt)  # an arm alone starts a takeoff PX4 holds on the ground
        if self._until is not None and now >= self._until:
            self._until = None
            if self.mode in ("land", "return_to_launch"):
                if self.mode == "return_to_launch":
                    self.lat, self.lon = self.home.lat, self.home.lon
                self.rel_alt, self.landed, self._touchdown, self.mode = 0.0, "on_ground", now, "land"
            elif self._target is not None:
                self.lat, self.lon, self.rel_alt = self._target
                if self.mode == "takeoff":
                    self.mode = "hold"
            self._target = None
        if self.armed and self._touchdown is not None and now - self._touchdown >= LAND_DISARM_S:
            self._disarm("auto")
        if self.armed and self._armed_at is not None and now - self._armed_at >= PREFLIGHT_DISARM_S:
            self._disarm("auto")

    def _report(self) -> None:
        self._reported = FcState(
            connected=True, armed=self.armed, flight_mode=self.mode, landed_state=self.landed,
            position=Position(lat=self.lat, lon=self.lon, alt=SPAWN[2] + self.rel_alt, rel_alt=self.rel_alt),
            home=self.home,
        )
        self.reports.append(Report(self.now, self._reported))
        self._changes.offer(self._reported)

    async def _run(self) -> None:
        await self.clock.sleep(self.phase_s)
        next_beat = self.now
        while True:
            self._step()
            if self.now >= next_beat - 1e-9:
                self._report()
                next_beat += self.heartbeat_s
            await self.clock.sleep(TICK_S)


def near(a: FcState, lat: float, lon: float) -> bool:
    return a.position is not None and distance_m(a.position.lat, a.position.lon, lat, lon) < 1.0


def north_of_spawn(m: float) -> tuple[float, float]:
    return destination(SPAWN[0], SPAWN[1], m, 0)
