"""The simulated multicopter: kinematics, modes, battery, GPS, health and faults.

A pure model stepped by `step(dt)`; whoever owns it (the agent's sim adapter, the
MAVLink endpoint, fast-time simulation) supplies time. Behaviour mirrors what PX4
v1.16 does towards MAVSDK (shared/notes/px4-facts.md, mavsdk-facts.md §6): takeoff
climbs at 1.5 m/s and switches to HOLD; land descends at 1.5 m/s above 5 m and
0.7 m/s below; the vehicle disarms itself 2 s after touchdown, or 10 s after arming
without a takeoff; offboard needs a setpoint fresher than 0.5 s to start and falls
back to HOLD when setpoints stop for 1 s; home is set at arming. The battery drains
while armed down to a floor and refills on disarm, as jMAVSim's does.

Commands return None when accepted or a short reason when denied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from dronefleet.schemas.geo import angle_diff_deg, normalize_deg
from dronefleet.schemas.telemetry import MANUAL_MODES, Battery, GpsInfo, Home, Position, VelocityNed
from dronefleet.sim.projection import LocalFrame

G = 9.81


@dataclass
class VehicleParams:
    """Tunables, named after the PX4 parameters they stand for."""

    takeoff_speed_mps: float = 1.5  # MPC_TKO_SPEED
    climb_speed_mps: float = 3.0  # MPC_Z_VEL_MAX_UP
    descent_speed_mps: float = 1.5  # MPC_Z_VEL_MAX_DN
    land_speed_mps: float = 0.7  # MPC_LAND_SPEED
    land_slow_below_m: float = 5.0  # MPC_LAND_ALT2
    cruise_speed_mps: float = 5.0  # MPC_XY_CRUISE
    max_speed_mps: float = 12.0  # MPC_XY_VEL_MAX
    yaw_rate_dps: float = 90.0
    takeoff_alt_m: float = 2.5  # MIS_TAKEOFF_ALT
    rtl_min_alt_m: float = 10.0
    disarm_after_land_s: float = 2.0  # COM_DISARM_LAND
    disarm_preflight_s: float = 10.0  # COM_DISARM_PRFLT
    offboard_fresh_s: float = 0.5
    offboard_loss_s: float = 1.0  # COM_OF_LOSS_T
    battery_drain_per_s: float = 0.0033
    battery_floor: float = 0.38
    battery_rtl_level: float = 0.10  # below this in the air: automatic RTL
    battery_cells: int = 4
    gps_satellites: int = 12
    # How a real autopilot gets going and comes to rest, where this model is otherwise
    # instant (autopilot_params.TIMING gives a make's; the built-in simulator leaves them off):
    takeoff_delay_s: float = 0.0  # from the takeoff command to the climb (PX4: COM_SPOOLUP_TIME + MPC_TKO_RAMP_T)
    accel_mps2: float = 0.0  # horizontal acceleration and braking (0: speed changes at once)
    land_alt1_m: float | None = None  # MPC_LAND_ALT1: from here down to land_slow_below_m the descent slows linearly
    land_detect_s: float = 0.0  # on the ground this long before the landing is detected


@dataclass
class _Setpoint:
    kind: str  # position_ned | velocity_ned | velocity_body | attitude | attitude_rate
    values: dict[str, float | None]
    at_s: float


@dataclass
class Vehicle:
    lat: float
    lon: float
    ground_alt: float  # terrain height AMSL at spawn, m
    params: VehicleParams = field(default_factory=VehicleParams)

    def __post_init__(self) -> None:
        self.frame = LocalFrame(self.lat, self.lon)
        self.t = 0.0
        self.north = self.east = 0.0
        self.alt = self.ground_alt
        self.vn = self.ve = self.vd = 0.0
        self.heading = 0.0
        self.armed = False
        self.mode = "hold"
        self.landed_state = "on_ground"
        self.home = Home(lat=self.lat, lon=self.lon, alt=self.ground_alt)
        self.battery = 1.0
        self.fix_type = "fix_3d"
        self.health_failures: set[str] = set()
        self.arm_denied: str | None = None  # a refusal no health flag reports (inject_arm_denied)
        self.connected = True
        self.cruise_speed = self.params.cruise_speed_mps
        self.events: list[str] = []  # status texts for whoever listens (STATUSTEXT)
        self.fence: list[tuple[float, float]] = []  # the autopilot's inclusion geofence [(lat, lon), …]; [] = none
        self._armed_at = 0.0
        self._landed_at: float | None = None
        self._touched_at: float | None = None  # on the ground, its landing not detected yet
        self._climb_at = 0.0  # a takeoff's climb starts then
        self._took_off = False
        self._takeoff_target = 0.0
        self._target: tuple[float, float, float] | None = None  # north, east, alt AMSL
        self._target_speed: float | None = None
        self._target_yaw: float | None = None
        self._rtl_phase = ""
        self._rtl_alt = 0.0
        self._setpoint: _Setpoint | None = None
        self._attitude = [0.0, 0.0]  # roll, pitch (deg) under attitude_rate
        self._mode_before_manual = "hold"
        self._battery_rtl_done = False

    # ----- derived state -------------------------------------------------------------

    @property
    def rel_alt(self) -> float:
        return self.alt - self.home.alt

    @property
    def in_air(self) -> bool:
        return self.landed_state != "on_ground"

    def position(self) -> Position:
        lat, lon = self.frame.to_global(self.north, self.east)
        return Position(lat=lat, lon=lon, alt=self.alt, rel_alt=self.rel_alt)

    def velocity(self) -> VelocityNed:
        return VelocityNed(north=self.vn, east=self.ve, down=self.vd)

    def speed(self) -> float:
        return math.sqrt(self.vn**2 + self.ve**2 + self.vd**2)

    def battery_state(self) -> Battery:
        per_cell = 3.5 + 0.7 * self.battery
        return Battery(remaining_percent=round(self.battery, 4), voltage=round(per_cell * self.params.battery_cells, 3))

    def gps(self) -> GpsInfo:
        sats = self.params.gps_satellites if self.fix_type not in ("no_gps", "no_fix") else 0
        return GpsInfo(satellites=sats, fix_type=self.fix_type)  # type: ignore[arg-type]

    def local_ned(self) -> tuple[float, float, float]:
        return self.north, self.east, -(self.alt - self.ground_alt)

    # ----- commands ------------------------------------------------------------------

    def arm(self) -> str | None:
        if self.armed:
            return None
        if self.health_failures:
            return f"arming denied: health check failed ({', '.join(sorted(self.health_failures))})"
        if self.fix_type in ("no_gps", "no_fix", "fix_2d"):
            return "arming denied: no 3D GPS fix"
        if self.arm_denied is not None:
            return f"arming denied: {self.arm_denied}"
        if self.mode in ("return_to_launch", "land", "mission"):
            return f"arming denied in mode {self.mode}"
        self.armed = True
        self._armed_at = self.t
        self._took_off = False
        self._landed_at = None
        pos = self.position()
        self.home = Home(lat=pos.lat, lon=pos.lon, alt=self.alt)
        self.events.append("Armed by external command")
        return None

    def disarm(self) -> str | None:
        if not self.armed:
            return None
        if self.in_air:
            return "disarm denied: in air"
        self._disarm("Disarmed by external command")
        return None

    def takeoff(self, alt_m: float | None = None) -> str | None:
        if not self.armed:
            return "takeoff denied: disarmed"
        if self.in_air:
            return "takeoff denied: already in air"
        if self.mode in MANUAL_MODES:
            return "takeoff denied: manual control"
        self._takeoff_target = alt_m if alt_m is not None else self.params.takeoff_alt_m
        self._climb_at = self.t + self.params.takeoff_delay_s
        self.mode = "takeoff"
        self.landed_state = "taking_off"
        self._took_off = True
        self._target = None
        return None

    def land(self) -> str | None:
        if not self.in_air:
            return None
        self.mode = "land"
        self.landed_state = "landing"
        self._target = None
        return None

    def goto(
        self, lat: float, lon: float, alt_amsl: float, yaw_deg: float | None = None, speed_mps: float | None = None
    ) -> str | None:
        if not self.armed:
            return "reposition denied: disarmed"
        if not self.in_air:
            return "reposition denied: on ground"
        north, east = self.frame.to_local(lat, lon)
        self.mode = "hold"
        if self.landed_state in ("taking_off", "landing"):
            self.landed_state = "in_air"
        self._target = (north, east, max(alt_amsl, self.ground_alt + 0.5))
        self._target_speed = speed_mps
        self._target_yaw = None if yaw_deg is None or math.isnan(yaw_deg) else normalize_deg(yaw_deg)
        return None

    def face(self, yaw_deg: float) -> str | None:
        """Turn to `yaw_deg` where it stands or flies to (ArduPilot's CONDITION_YAW)."""
        if not self.armed or not self.in_air:
            return "yaw denied: on ground"
        self._target_yaw = normalize_deg(yaw_deg)
        return None

    def hold(self) -> str | None:
        if self.mode in MANUAL_MODES:
            return "hold denied: manual control"
        self.mode = "hold"
        if self.in_air:
            if self.landed_state in ("taking_off", "landing"):
                self.landed_state = "in_air"
            self._target = (self.north, self.east, self.alt)
            self._target_speed = None
            self._target_yaw = None
        return None

    def return_to_launch(self, alt_m: float | None = None) -> str | None:
        if not self.armed or not self.in_air:
            return None  # nothing to do on the ground; PX4 accepts the mode switch
        self.mode = "return_to_launch"
        self.landed_state = "in_air"
        self._rtl_phase = "climb"
        wanted = max(alt_m if alt_m is not None else 0.0, self.params.rtl_min_alt_m)
        self._rtl_alt = self.home.alt + max(wanted, self.rel_alt)
        self._target = None
        return None

    def set_speed(self, speed_mps: float) -> str | None:
        if not 0 < speed_mps <= self.params.max_speed_mps:
            return f"speed {speed_mps} out of range (0, {self.params.max_speed_mps}]"
        self.cruise_speed = speed_mps
        return None

    def set_setpoint(self, kind: str, **values: float | None) -> None:
        self._setpoint = _Setpoint(kind, values, self.t)

    def start_offboard(self) -> str | None:
        if self._setpoint is None or self.t - self._setpoint.at_s > self.params.offboard_fresh_s:
            return "offboard denied: no setpoint streaming"
        if self.mode in MANUAL_MODES:
            return "offboard denied: manual control"
        self.mode = "offboard"
        if self._setpoint.kind == "attitude_rate":
            self._attitude = [0.0, 0.0]
        return None

    def stop_offboard(self) -> str | None:
        if self.mode != "offboard":
            return None
        return self.hold()

    # ----- fault injection -----------------------------------------------------------

    def inject_manual(self, active: bool) -> None:
        """A pilot takes (or gives back) the radio: position mode, holding still."""
        if active and self.mode not in MANUAL_MODES:
            self._mode_before_manual = self.mode
            self.mode = "posctl"
            self._target = (self.north, self.east, self.alt)
            self.events.append("RC override: position mode")
        elif not active and self.mode in MANUAL_MODES:
            self.mode = "hold"
            self._target = (self.north, self.east, self.alt) if self.in_air else None
            self.events.append("RC released")

    def inject_health_failure(self, *checks: str) -> None:
        self.health_failures = set(checks)

    def inject_arm_denied(self, reason: str | None) -> None:
        """The autopilot refuses to arm with `reason` though its health flags read fine
        (a preflight check no flag reports, as PX4's and ArduPilot's have); None arms again."""
        self.arm_denied = reason

    def inject_gps(self, fix_type: str) -> None:
        self.fix_type = fix_type

    def inject_battery(self, remaining: float) -> None:
        self.battery = max(0.0, min(1.0, remaining))

    def inject_gust(self, east_m: float) -> None:
        """A gust sets the drone down `east_m` metres east (west if negative) of where it
        was; the autopilot then holds or flies on from there."""
        self.east += east_m
        if self.mode == "hold" and self._target is not None:
            self._target = (self._target[0], self._target[1] + east_m, self._target[2])

    def inject_link_loss(self, lost: bool) -> None:
        """The flight controller stops talking (cable pulled, FC reset)."""
        self.connected = not lost

    # ----- dynamics ------------------------------------------------------------------

    def step(self, dt: float) -> None:
        if dt <= 0:
            return
        self.t += dt
        p = self.params
        if self.armed and self.battery > p.battery_floor:  # an injected lower value stays
            self.battery = max(p.battery_floor, self.battery - p.battery_drain_per_s * dt)
        if (
            self.armed and self.in_air and self.battery <= p.battery_rtl_level
            and not self._battery_rtl_done and self.mode not in ("return_to_launch", "land")
            and self.mode not in MANUAL_MODES
        ):
            self._battery_rtl_done = True
            self.events.append("Low battery: returning to launch")
            self.return_to_launch(None)

        self._step_mode(dt)
        self.north += self.vn * dt
        self.east += self.ve * dt
        self.alt -= self.vd * dt
        if self.alt <= self.ground_alt:
            self.alt = self.ground_alt
            if self.vd > 0:
                self.vd = 0.0
        self._update_landed()
        self._auto_disarm()

    def _step_mode(self, dt: float) -> None:
        p = self.params
        if not self.armed:
            self.vn = self.ve = self.vd = 0.0
            return
        mode = self.mode
        if mode == "takeoff":
            self.vn = self.ve = 0.0
            top = self.home.alt + self._takeoff_target
            if self.t < self._climb_at:
                self.vd = 0.0
            elif top - self.alt > 1e-3:
                self.vd = -self._vertical_rate(top - self.alt, p.takeoff_speed_mps, dt)
            else:
                self.vd = 0.0
                self.mode = "hold"
                self.landed_state = "in_air"
                self._target = (self.north, self.east, top)
                self.events.append("Takeoff complete")
        elif mode == "land":
            self._descend(dt)
        elif mode == "return_to_launch":
            self._step_rtl(dt)
        elif mode == "offboard":
            self._step_offboard(dt)
        elif self.in_air:  # hold, manual modes: fly to / stay at the target
            if self._target is None:
                self._target = (self.north, self.east, self.alt)
            self._fly_to(self._target, self._target_speed or self.cruise_speed, dt)
            if self._target_yaw is not None:
                self._turn_to(self._target_yaw, dt)
        else:
            self.vn = self.ve = self.vd = 0.0

    def _step_rtl(self, dt: float) -> None:
        p = self.params
        home_n, home_e = self.frame.to_local(self.home.lat, self.home.lon)
        if self._rtl_phase == "climb":
            self.vn = self.ve = 0.0
            self.vd = -self._vertical_rate(self._rtl_alt - self.alt, p.climb_speed_mps, dt)
            if abs(self._rtl_alt - self.alt) < 1e-3:
                self._rtl_phase = "fly"
        if self._rtl_phase == "fly":
            self._turn_to(math.degrees(math.atan2(home_e - self.east, home_n - self.north)), dt)
            if self._fly_to((home_n, home_e, self._rtl_alt), self.cruise_speed, dt):
                self._rtl_phase = "land"
        if self._rtl_phase == "land":
            self._descend(dt)
            if self.landed_state != "on_ground":
                self.landed_state = "landing"

    def _step_offboard(self, dt: float) -> None:
        p = self.params
        sp = self._setpoint
        if sp is None or self.t - sp.at_s > p.offboard_loss_s:
            self.events.append("Offboard setpoints lost: holding")
            self.hold()
            return
        v = {k: (0.0 if val is None else val) for k, val in sp.values.items()}
        if sp.kind == "position_ned":
            target_alt = self.ground_alt - v.get("down", 0.0)
            self._fly_to((v.get("north", 0.0), v.get("east", 0.0), target_alt), self.cruise_speed, dt)
            if sp.values.get("yaw") is not None:
                self._turn_to(v["yaw"], dt)
            return
        if sp.kind == "velocity_ned":
            self.vn, self.ve, self.vd = v.get("north", 0.0), v.get("east", 0.0), v.get("down", 0.0)
            if sp.values.get("yaw") is not None:
                self._turn_to(v["yaw"], dt)
        elif sp.kind == "velocity_body":
            self._set_body_velocity(v.get("forward", 0.0), v.get("right", 0.0), v.get("down", 0.0))
            self.heading = normalize_deg(self.heading + v.get("yaw", 0.0) * dt)
        else:  # attitude / attitude_rate: tilt maps to horizontal speed, thrust to climb
            if sp.kind == "attitude_rate":
                self._attitude[0] = _clamp(self._attitude[0] + v.get("roll", 0.0) * dt, 35.0)
                self._attitude[1] = _clamp(self._attitude[1] + v.get("pitch", 0.0) * dt, 35.0)
                roll, pitch = self._attitude
                self.heading = normalize_deg(self.heading + v.get("yaw", 0.0) * dt)
            else:
                roll, pitch = v.get("roll", 0.0), v.get("pitch", 0.0)
                self._turn_to(v.get("yaw", 0.0), dt)
            gain = p.max_speed_mps / 35.0
            self._set_body_velocity(-pitch * gain, roll * gain, -(v.get("thrust", 0.5) - 0.5) * 2 * p.climb_speed_mps)
        speed = math.hypot(self.vn, self.ve)
        if speed > p.max_speed_mps:
            self.vn *= p.max_speed_mps / speed
            self.ve *= p.max_speed_mps / speed
        if self.alt <= self.ground_alt and self.vd > 0:
            self.vd = 0.0

    # ----- helpers -------------------------------------------------------------------

    def _set_body_velocity(self, forward: float, right: float, down: float) -> None:
        h = math.radians(self.heading)
        self.vn = forward * math.cos(h) - right * math.sin(h)
        self.ve = forward * math.sin(h) + right * math.cos(h)
        self.vd = down

    def _descend(self, dt: float) -> None:
        """Land where it is: fast above MPC_LAND_ALT1, slowing linearly down to
        MPC_LAND_ALT2 (with no ALT1: at once), slow below, stop at the ground."""
        p = self.params
        self.vn = self.ve = 0.0
        alt, low, high = self.rel_alt, p.land_slow_below_m, p.land_alt1_m
        if alt <= low:
            rate = p.land_speed_mps
        elif high is None or alt >= high or high <= low:
            rate = p.descent_speed_mps
        else:
            rate = p.land_speed_mps + (alt - low) / (high - low) * (p.descent_speed_mps - p.land_speed_mps)
        self.vd = min(rate, (self.alt - self.ground_alt) / dt)

    def _vertical_rate(self, dz: float, rate: float, dt: float) -> float:
        """Signed climb rate (m/s, up positive) that closes dz without overshooting."""
        return math.copysign(min(rate, abs(dz) / dt), dz)

    def _fly_to(self, target: tuple[float, float, float], speed: float, dt: float) -> bool:
        """Set velocity towards target (limited per axis, no overshoot); True when there."""
        p = self.params
        dn, de = target[0] - self.north, target[1] - self.east
        dist = math.hypot(dn, de)
        speed = min(speed, p.max_speed_mps)
        if dist > 1e-6:
            step = min(speed, dist / dt)
            if p.accel_mps2 > 0:  # speeding up from where it is, braking (in steps of dt) to stop there
                brake = p.accel_mps2 * dt / 2
                step = min(step, math.hypot(self.vn, self.ve) + p.accel_mps2 * dt,
                           math.sqrt(brake * brake + 2 * p.accel_mps2 * dist) - brake)
            self.vn, self.ve = dn / dist * step, de / dist * step
        else:
            self.vn = self.ve = 0.0
        dz = target[2] - self.alt
        rate = p.climb_speed_mps if dz > 0 else p.descent_speed_mps
        self.vd = -self._vertical_rate(dz, rate, dt) if abs(dz) > 1e-6 else 0.0
        return dist <= 1e-3 and abs(dz) <= 1e-3

    def _turn_to(self, yaw: float, dt: float) -> None:
        diff = angle_diff_deg(yaw, self.heading)
        max_step = self.params.yaw_rate_dps * dt
        self.heading = normalize_deg(self.heading + max(-max_step, min(max_step, diff)))

    def _update_landed(self) -> None:
        on_ground = self.alt <= self.ground_alt + 1e-3
        if self.mode == "takeoff" and self.armed:
            self.landed_state = "taking_off"
        elif on_ground and self.vd >= 0 and self.landed_state != "on_ground" and self._took_off:
            if self._touched_at is None:
                self._touched_at = self.t
            if self.t - self._touched_at < self.params.land_detect_s:
                return
            self._touched_at = None
            self.landed_state = "on_ground"
            self._landed_at = self.t
            self.vn = self.ve = self.vd = 0.0
            self.events.append("Landing detected")
        elif not on_ground and self.landed_state == "on_ground":
            self.landed_state = "in_air"
        if not on_ground:
            self._touched_at = None

    def _auto_disarm(self) -> None:
        if not self.armed or self.in_air:
            return
        p = self.params
        if self._landed_at is not None and self.t - self._landed_at >= p.disarm_after_land_s:
            self._disarm("Disarmed by landing")
        elif not self._took_off and self.t - self._armed_at >= p.disarm_preflight_s and self.mode != "takeoff":
            self._disarm("Disarmed: no takeoff after arming")

    def _disarm(self, why: str) -> None:
        self.armed = False
        self.vn = self.ve = self.vd = 0.0
        self.battery = 1.0  # a fresh pack, as jMAVSim does
        self._battery_rtl_done = False
        self._landed_at = None
        self._took_off = False
        self._target = None
        if self.mode not in MANUAL_MODES:
            self.mode = "hold"
        self.events.append(why)


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))
