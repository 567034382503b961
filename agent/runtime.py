"""The running agent: a flight controller, the command handler and the bus, wired.

Start order: flight controller (exit fast if it is unreachable), then the agent's
own Zenoh router (ADR 0003: it joins the mesh, reaches the ground directly or through
neighbours, and serves on-board programs even while the ground is gone), then the
liveliness token, the command and ping queryables, the publishing loops, the link
probe and the lost-link watch. Shutdown runs in reverse, in `finally`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import msgspec

from dronefleet.agent.bundle import BundleRunner, BundleStore
from dronefleet.agent.config import AgentConfig, own_endpoint
from dronefleet.agent.fc_port import FcError, FcState, FcUnavailable, FlightController
from dronefleet.agent.footprint import HEAP_TRIM_EVERY_S, HEAP_TRIM_FIRST_S, release_freed_heap
from dronefleet.agent.ground_fence import GroundFence
from dronefleet.agent.handler import CommandHandler, FlightSettings
from dronefleet.agent.link import LostLink, LostLinkAction
from dronefleet.agent.neighbours import Neighbours, new_bridge_zids
from dronefleet.agent.prober import LinkProber
from dronefleet.agent.status_resend import StatusResend
from dronefleet.agent.telemetry_filter import to_telemetry
from dronefleet.bus.clock import Clock, SystemClock
from dronefleet.bus.datagram_echo import EchoPort, UdpEcho
from dronefleet.bus.mesh_policy import unsure
from dronefleet.bus.port import Bus, Sample, echo
from dronefleet.bus.redeclarable import Redeclarable
from dronefleet.schemas.about import About
from dronefleet.schemas.auth import verifier_of
from dronefleet.schemas.bundles import BundleReply, BundleStatus, parse_bundle
from dronefleet.schemas.codec import decode_sensor, encode
from dronefleet.schemas.commands import Cancel, CommandReply, Land, Return, decode_command
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.grounds import STALE_GROUND, ActiveGround
from dronefleet.schemas.keys import Keys, check_id
from dronefleet.schemas.status import FAILSAFE_ID_PREFIX, GEOFENCE_OUTSIDE, CommandStatus, SystemStatus
from dronefleet.schemas.telemetry import GROUND_PEER, Telemetry

log = logging.getLogger(__name__)
FC_CONNECT_TIMEOUT_S = 8.0
# Told to stop (SIGTERM), the agent closes its Zenoh session (2 s at most, CLOSE_WAIT_S)
# and its MAVSDK instance; still there after this long, it prints every thread's stack
# and exits 1 (cli_kit.run_async): a clean-up stuck in a native call must not keep a
# supervisor's stop waiting, and its stacks say where it is stuck.
STOP_GRACE_S = 8.0
LOST_LINK_TICK_S = 0.2
# On the ground no failsafe or fence return is taken, only the link warning (then up to a
# second later): the checks tick this often there, so an idle agent wakes less.
RESTING_TICK_S = 1.0
JOIN_WAIT_S = 2.0  # at start, how long to wait for the ground before serving without it
# A contact gap this long may have been a link closing and the mesh routing the drone
# another way: its command and bundle queryables are declared afresh (ADR 0003).
REDECLARE_AFTER_S = 2.0
# The ground says it hears the drone but holds no route to its commands (issue 76): they
# are declared afresh, at most this often, so that each declaration has time to cross.
REDECLARE_ASKED_MIN_S = 2.0
FAILSAFE_COMMANDS = {"hold": Cancel, "return": Return, "land": Land}
GEOFENCE_ID_PREFIX = "geofence-"


def make_flight_controller(url: str, clock: Clock) -> FlightController:
    """The adapter for `--fc`; each imports only its own libraries (agent/footprint.py)."""
    if url == "sim" or url.startswith("sim://"):
        from dronefleet.agent.fc_sim import SimFlightController, parse_sim_url

        vehicle, control_port = parse_sim_url(url)
        return SimFlightController(vehicle, clock, control_port)
    from dronefleet.agent.fc_mavsdk import MavsdkFlightController

    return MavsdkFlightController(url, connect_timeout_s=FC_CONNECT_TIMEOUT_S)


class Agent:
    def __init__(
        self, drone_id: str, config: AgentConfig, fc: FlightController, bus: Bus, clock: Clock,
        echo: EchoPort | None = None,
    ) -> None:
        """`echo`: datagram trains to the ground's echo, for the loss of the path
        (agent/prober.py); without one, quality comes from the Zenoh probes alone."""
        self.drone_id = check_id(drone_id)
        self.config = config
        self.keys = Keys(config.namespace)
        self.fc = fc
        self.bus = bus
        self.clock = clock
        settings = FlightSettings(
            acceptance_radius=config.acceptance_radius,
            takeoff_altitude=config.takeoff_altitude,
            return_altitude=config.return_altitude,
            max_speed=config.max_speed,
            geofence=config.geofence,
        )
        self.handler = CommandHandler(self.drone_id, fc, settings, clock, self._publish_status)
        security = config.security
        self.verifier = verifier_of(security.pki_dir, security.ground_key, security.window_s)
        self._seq = 0
        store = BundleStore(Path(config.state_dir) / "bundles.json" if config.state_dir else None)
        self.bundles = BundleRunner(self.drone_id, self.handler, clock, self._publish_status, self._telemetry_now, store)
        self.resend = StatusResend(config.probe_period_ms)  # what to send again after a gap
        self._served: list[Redeclarable] = []  # the command and bundle queryables, while running
        self.fence = GroundFence()  # SPEC §14: the newest ground epoch heard and its ground; others are refused
        self.lost_link = LostLink(config.lost_link, clock.monotonic(), steady_gap_s=2 * config.probe_period_ms / 1000)
        self.prober = LinkProber(
            self.drone_id, bus, self.keys, clock, config.probe_period_ms / 1000,
            on_ground_contact=self._on_ground_contact, window=config.probe_window, echo=echo,
            on_unrouted=self._on_unrouted,
        )
        self._redeclared_at = -math.inf

    def _system(self, state: str, reason: str | None = None) -> None:
        self._publish_status(SystemStatus(
            drone_id=self.drone_id, timestamp=self.clock.time_ms(), component="system",
            state=state, reason=reason,  # type: ignore[arg-type]
        ))

    def ground_silent(self) -> bool:  # no answer from the ground for two probe periods
        return self.lost_link.silent(self.clock.monotonic())

    def ground_heard_at(self) -> float:
        return self.lost_link.last_contact

    def ground_unsure(self) -> bool:
        """The ground silent, one of its last probes lost or retransmitted, or the one out
        overdue: the drone links through good neighbours before its link is lost (ADR 0003)."""
        return (self.ground_silent() or self.prober.ground_overdue(self.clock.monotonic())
                or unsure(self.prober.windows[GROUND_PEER].outcomes()))

    def _on_ground_contact(self, now: float) -> None:
        now_ms = self.clock.time_ms()
        for decision, summary in self.lost_link.contact(now):
            log.warning("%s: ground reachable again, %s", self.drone_id, summary)
            self._system(decision, summary)
        if not self.resend.contacted:
            self._publish_about()  # a ground that started after this agent hears what it is
        # What was published before the ground's subscriptions reached this router, or
        # while a link that closed carried it, may have gone nowhere (agent/status_resend.py).
        contact = self.resend.contact(now_ms)
        if contact.gap_ms is not None and contact.gap_ms >= REDECLARE_AFTER_S * 1000 and self._served:
            log.info("%s: the ground answers again after %.1f s; declaring its command queryables afresh",
                     self.drone_id, contact.gap_ms / 1000)
            self._redeclare()
        for repeat in contact.repeats:
            log.info("%s: repeating %d %s", self.drone_id, len(repeat.statuses), repeat.why)
            for status in repeat.statuses:
                self.bus.publish(self.keys.status(self.drone_id), encode(status), reliable=True)

    def _on_unrouted(self) -> None:
        """The ground's answer to a probe: it hears this drone, but its router holds no
        route to the command queryable (a declaration that did not cross when the mesh
        routed the drone another way, ADR 0003)."""
        if self._served and self.clock.monotonic() - self._redeclared_at >= REDECLARE_ASKED_MIN_S:
            log.info("%s: the ground hears it but cannot reach its commands; declaring its command queryables afresh",
                     self.drone_id)
            self._redeclare()

    def _redeclare(self) -> None:
        self._redeclared_at = self.clock.monotonic()
        for served in self._served:
            served.refresh()

    def _signed_by_the_ground(self) -> None:
        """A command or bundle that passed the ground's signature is contact (SPEC §8), as an
        answered probe is."""
        if self.verifier is not None:
            self._on_ground_contact(self.clock.monotonic())

    async def _lost_link_loop(self) -> None:
        while True:
            state = self.fc.state()
            flying = _flying(state)
            # While a bundle runs, its own on_link_loss decides (below); the agent's
            # failsafe waits until the bundle has ended.
            alone = flying and not self.bundles.running
            for decision, action in self.lost_link.tick(self.clock.monotonic(), alone):
                if decision == "failsafe":
                    self._failsafe(action)  # type: ignore[arg-type]
                else:
                    log.warning("%s: no answer from the ground for %g s", self.drone_id, self.config.lost_link.timeout_s)
                    self._system(decision, f"no answer from the ground for {self.config.lost_link.timeout_s:g} s")
                    policy = self.bundles.end_for_link_loss()
                    if policy is not None:  # the bundle's own policy, instead of the agent's
                        self.lost_link.acted_alone(policy, self.clock.monotonic())  # type: ignore[arg-type]
                        self._system("failsafe", policy)
            await self.clock.sleep(_check_every_s(flying))

    def _failsafe(self, action: LostLinkAction, why: str | None = None) -> None:
        """Act alone: the same handler and priority rules as a command from the ground.
        Without `why`, for the lost link (a command it ends is sent again by the
        mission once the link is back); else the reason, e.g. the geofence's."""
        running = self.handler.running
        if why is None and (running == "land" or (running == "return" and action != "land")):
            # Already on its way down or home: a hold would stop it in the air, out of reach.
            log.warning("%s: lost link failsafe: %s not taken, the drone is already running %s",
                        self.drone_id, action, running)
            return
        now_ms = self.clock.time_ms()  # one failsafe per action at a time: unique, and replays in fast time
        prefix = FAILSAFE_ID_PREFIX if why is None else GEOFENCE_ID_PREFIX
        command = FAILSAFE_COMMANDS[action](drone_id=self.drone_id, command_id=f"{prefix}{action}-{now_ms}", timestamp=now_ms)
        reply = self.handler.submit(command)
        log.warning("%s: %s failsafe: %s (%s)", self.drone_id, why or "lost link", action,
                    "accepted" if reply.accepted else f"refused: {reply.reason}")
        self._system("failsafe", action if why is None else f"{action}: {why}")

    async def _fence_loop(self) -> None:
        """SPEC §11: a flying drone found outside the geofence (an offboard setpoint, a
        wind, a fence changed under it) returns, once per excursion."""
        fence, out = self.config.geofence, False
        while True:
            s = self.fc.state()
            flying = _flying(s)
            where = fence.outside(s.position.lat, s.position.lon, s.position.rel_alt) if flying and s.position else None
            if where is not None and not out:
                self._failsafe("return", f"{GEOFENCE_OUTSIDE}, {where}")
            out = where is not None
            await self.clock.sleep(_check_every_s(flying))

    async def _upload_fence(self) -> None:
        """The fence's polygon as the autopilot's own geofence, where it takes one."""
        polygon = [(lat, lon) for lat, lon in self.config.geofence.polygon]
        try:
            await self.fc.upload_fence(polygon)
            log.info("%s: geofence of %d vertices uploaded to the flight controller", self.drone_id, len(polygon))
        except FcError as exc:  # the agent's own checks and watch still hold
            log.warning("%s: the flight controller did not take the geofence: %s", self.drone_id, exc)

    def _publish_status(self, status: CommandStatus | SystemStatus | BundleStatus) -> None:
        self.bus.publish(self.keys.status(self.drone_id), encode(status), reliable=True)
        self.resend.published(status)
        if isinstance(status, CommandStatus):
            self.bundles.on_status(status)

    def about(self) -> About:
        c = self.config
        return About(drone_id=self.drone_id, timestamp=self.clock.time_ms(), kind=c.kind, roles=list(c.roles),
                     sensors=list(c.sensors), autopilot=self.fc.make)

    def _publish_about(self) -> None:
        self.bus.publish(self.keys.about(self.drone_id), encode(self.about()), reliable=True)

    async def _on_about(self, selector: str, payload: bytes) -> bytes:
        return encode(self.about())

    def _telemetry_now(self) -> Telemetry | None:
        state = self.fc.state()
        return to_telemetry(self.drone_id, self._seq, self.clock.time_ms(), state) if state.position is not None else None

    def _on_sensor(self, sample: Sample) -> None:
        """On-board sensor readings: the bundle guards' `sensor.<type>` values."""
        try:
            reading = decode_sensor(sample.payload)
        except InvalidMessage:
            return
        self.bundles.sensors[sample.key.rsplit("/", 1)[-1]] = reading.data

    def _not_mine(self, drone_id: str) -> str | None:
        """Why a request naming another drone is refused (no name: it is for us)."""
        return f"drone_id: this is {self.drone_id}, not {drone_id}" if drone_id and drone_id != self.drone_id else None

    def _stale(self, epoch: int, ground_id: str, what: str, message_id: str) -> str | None:
        """SPEC §14 fencing (agent/ground_fence.py): a command or bundle from a ground
        older than the newest heard, or of the same epoch from another ground, is refused
        `stale_ground`; a newer one raises what is heard."""
        if self.fence.admits(epoch, ground_id):
            return None
        log.warning("%s: refused %s %s from ground %s of epoch %d: epoch %d of %s is active (stale_ground)",
                    self.drone_id, what, message_id or "?", ground_id or "?", epoch, self.fence.epoch,
                    self.fence.holder or "?")
        return STALE_GROUND

    def _on_active_ground(self, sample: Sample) -> None:
        """A ground says it is active: its epoch is the newest heard if it is higher."""
        try:
            said = msgspec.json.decode(sample.payload, type=ActiveGround)
        except msgspec.MsgspecError:
            return
        if self.fence.heard(said.epoch, said.ground_id):
            log.info("%s: ground %s is active (epoch %d)", self.drone_id, said.ground_id, said.epoch)

    def _unauthenticated(self, message: Any, message_id: str) -> str | None:
        """SPEC §9: with the ground's key configured, why a command or bundle is refused."""
        if self.verifier is None:
            return None
        reason = self.verifier.refusal(message, message_id, self.clock.time_ms())
        if reason is not None:
            log.warning("%s: refused %s %s: %s", self.drone_id, type(message).__name__.lower(), message_id or "?", reason)
        return reason

    async def _on_bundle(self, selector: str, payload: bytes) -> bytes:
        """A TaskBundle to run, or (no payload, `?id=…`) the record of one."""
        if not payload:
            params = dict(p.split("=", 1) for p in selector.partition("?")[2].split(";") if "=" in p)
            bundle_id = params.get("id", "")
            record = self.bundles.store.get(bundle_id)
            if record is None:
                raise LookupError(f"no bundle {bundle_id!r} on {self.drone_id}" if bundle_id else "give ?id=<bundle_id>")
            return encode(record)
        try:
            bundle = parse_bundle(payload)
        except InvalidMessage as exc:
            log.warning("%s: refused a bundle: %s", self.drone_id, exc)
            return encode(BundleReply(bundle_id=_peek(payload, "bundle_id"), accepted=False, reason=str(exc)))
        wrong = (self._not_mine(bundle.wire.drone_id) or self._unauthenticated(bundle.wire, bundle.bundle_id)
                 or self._stale(bundle.wire.ground_epoch, bundle.wire.ground_id, "bundle", bundle.bundle_id))
        if wrong is not None:
            return encode(BundleReply(bundle_id=bundle.bundle_id, accepted=False, reason=wrong,
                                      ground_epoch=self.fence.epoch if wrong == STALE_GROUND else None))
        self._signed_by_the_ground()
        return encode(self.bundles.submit(bundle))

    async def _on_command(self, key: str, payload: bytes) -> bytes:
        try:
            cmd = decode_command(payload)
        except InvalidMessage as exc:
            log.warning("%s: refused a malformed command: %s", self.drone_id, exc)
            return encode(CommandReply(command_id=_peek(payload, "command_id"), accepted=False, reason=str(exc)))
        wrong = (self._not_mine(cmd.drone_id) or self._unauthenticated(cmd, cmd.command_id)
                 or self._stale(cmd.ground_epoch, cmd.ground_id, cmd.name, cmd.command_id))
        if wrong is not None:
            return encode(CommandReply(command_id=cmd.command_id, accepted=False, reason=wrong,
                                       ground_epoch=self.fence.epoch if wrong == STALE_GROUND else None))
        self._signed_by_the_ground()
        if not cmd.command_id:
            cmd = msgspec.structs.replace(cmd, command_id=str(uuid.uuid4()))
        reply = self.handler.submit(cmd)
        if reply.accepted and self.bundles.running:  # the ground takes over
            self.bundles.interrupt(f"{cmd.name} from the ground")
        return encode(reply)

    def _publish_telemetry(self) -> None:
        state = self.fc.state()
        if state.position is not None:
            self._seq += 1
            telem = to_telemetry(self.drone_id, self._seq, self.clock.time_ms(), state)
            self.bus.publish(self.keys.telem(self.drone_id), encode(telem), reliable=False)

    def _on_link_closed(self) -> None:
        """A link closed (a lossy hop's lease ran out): the ground hears the drone over the new way now (ADR 0003)."""
        self._publish_telemetry()

    async def _telemetry_loop(self) -> None:
        """Sooner while the ground is in doubt: over a lossy hop each sample is one more chance (ADR 0003)."""
        period, in_doubt = self.config.telemetry_rate_ms / 1000, self.config.doubt_telemetry_rate_ms / 1000
        next_at = self.clock.monotonic()
        while True:
            self._publish_telemetry()
            next_at += (step := min(in_doubt, period) if self.ground_unsure() else period)
            now = self.clock.monotonic()
            if next_at < now + step / 2:  # late (a loaded machine): skip what was missed, never a burst of stale samples
                next_at = now + step
            await self.clock.sleep(next_at - now)

    async def run(self) -> None:
        """Serve until cancelled. The caller owns (and closes) fc and bus."""
        # Queryable first: once the liveliness token is visible, commands are served.
        self._served = [Redeclarable(self.bus, self.keys.cmd(self.drone_id), self._on_command, self.clock),
                        Redeclarable(self.bus, self.keys.bundle(self.drone_id), self._on_bundle, self.clock)]
        sensors = self.bus.subscribe(self.keys.sensor(self.drone_id), self._on_sensor, latest_only=True)
        grounds = self.bus.subscribe(self.keys.ground("*", "active"), self._on_active_ground)
        ping = self.bus.serve(self.keys.ping(self.drone_id), echo)
        about = self.bus.serve(self.keys.about(self.drone_id), self._on_about)
        token = self.bus.announce(self.keys.alive(self.drone_id))
        links = self.bus.watch_links(self._on_link_closed)
        self._publish_about()
        log.info("%s: serving commands on %s", self.drone_id, self.keys.cmd(self.drone_id))
        self.bundles.recover()
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self.handler.run(), name=f"{self.drone_id} handler")
                tg.create_task(self._telemetry_loop(), name=f"{self.drone_id} telemetry")
                tg.create_task(self.prober.run(), name=f"{self.drone_id} link probe")
                tg.create_task(self._lost_link_loop(), name=f"{self.drone_id} lost link")
                if self.config.geofence.limits:
                    tg.create_task(self._fence_loop(), name=f"{self.drone_id} geofence")
                if self.config.geofence.polygon:
                    tg.create_task(self._upload_fence(), name=f"{self.drone_id} geofence upload")
        finally:
            await self.bundles.close()
            links.close()
            token.close()
            about.close()
            ping.close()
            grounds.close()
            sensors.close()
            for served in self._served:
                served.close()
            self._served = []


def _flying(state: FcState) -> bool:
    return state.armed and state.landed_state not in ("on_ground", "unknown")


def _check_every_s(flying: bool) -> float:
    """How often the lost-link and fence checks look: in the air they bound a failsafe's delay."""
    return LOST_LINK_TICK_S if flying else RESTING_TICK_S


async def _join(bus: Bus, keys: Keys, drone_id: str) -> None:
    """A router connects in the background (measured: the first put right after open
    is lost). Give the ground JOIN_WAIT_S to appear so the agent's first statuses are
    heard; without it the agent serves its on-board programs all the same."""
    seen = asyncio.Event()
    watch = bus.watch_liveliness(keys.ground_alive(), lambda key, alive: seen.set() if alive else None)
    try:
        async with asyncio.timeout(JOIN_WAIT_S):
            await seen.wait()
    except TimeoutError:
        log.warning("%s: the ground is not reachable yet; serving without it", drone_id)
    finally:
        watch.close()


def _peek(payload: bytes, field: str) -> str:
    """A string field of a payload that did not decode (for the refusal's id)."""
    try:
        value = json.loads(payload).get(field, "")
        return value if isinstance(value, str) else ""
    except (ValueError, AttributeError, TypeError):
        return ""


async def _release_freed_heap() -> None:
    """Start-up's freed memory back to the system once the agent serves, then after each
    minute's churn (agent/footprint.py)."""
    await asyncio.sleep(HEAP_TRIM_FIRST_S)
    while True:
        release_freed_heap()
        await asyncio.sleep(HEAP_TRIM_EVERY_S)


async def run_agent(drone_id: str, config: AgentConfig, clock: Clock | None = None) -> None:
    """The `fleet agent` process: real flight controller, real Zenoh, until cancelled."""
    from dronefleet.bus.mesh_security import mesh_security
    from dronefleet.bus.zenoh_bus import ZenohBus

    clock = clock or SystemClock()
    # MAVSDK runs its blocking calls in the default executor; 6 threads on 2 cores
    # serialise a burst of commands (mavsdk-facts.md §2.1).
    asyncio.get_running_loop().set_default_executor(ThreadPoolExecutor(32, thread_name_prefix="fc"))
    # Checked before anything starts: a missing certificate is a configuration error.
    bridge_zids = new_bridge_zids() if config.mesh_interface else frozenset()
    secured = mesh_security(config.security, drone_id, [*config.connect, *config.listen], router=True,
                            namespace=config.namespace, bridge_zids=bridge_zids)
    fc = make_flight_controller(config.fc, clock)
    try:
        async with asyncio.timeout(FC_CONNECT_TIMEOUT_S + 2):
            await fc.start()
    except TimeoutError:
        await fc.close()
        raise FcUnavailable(f"no flight controller answered on {config.fc} within {FC_CONNECT_TIMEOUT_S:g} s") from None
    try:
        log.info("%s: flight controller %s connected; router on %s joins the mesh via %s",
                 drone_id, config.fc, ", ".join(config.listen) or "(no listener)", ", ".join(config.connect))
        bus = await ZenohBus.open("router", config.connect, config.listen, mesh_interface=config.mesh_interface,
                                  extra=secured)
        try:
            await _join(bus, Keys(config.namespace), drone_id)
            echo = await UdpEcho.open(config.connect)
            heap = asyncio.get_running_loop().create_task(_release_freed_heap(), name="heap release")
            try:
                agent = Agent(drone_id, config, fc, bus, clock, echo=echo)
                if config.mesh_interface is None:
                    await agent.run()
                else:
                    async with asyncio.TaskGroup() as tg:
                        tg.create_task(agent.run(), name=f"{drone_id} agent")
                        neighbours = Neighbours(drone_id, bus, config.mesh_interface, config.connect,
                                                own_endpoint(config.listen) or "", agent, extra=secured,
                                                zids=bridge_zids)
                        tg.create_task(neighbours.run(), name=f"{drone_id} neighbours")
            finally:
                heap.cancel()
                if echo is not None:
                    echo.close()
        finally:
            await bus.close()
    finally:
        await fc.close()
