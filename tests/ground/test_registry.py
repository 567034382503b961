"""The fleet registry as pure logic: events in, state and thesis-style log lines out."""

from __future__ import annotations

from typing import Any

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dronefleet.ground.config import GroundConfig
from dronefleet.ground.registry import ABOUTS_UNREGISTERED_KEPT, UNANNOUNCED_BURST, InfoChanged, LogLine, Registry
from dronefleet.schemas.about import About
from dronefleet.schemas.status import CommandStatus, Coords, SystemStatus
from dronefleet.schemas.telemetry import Battery, Position, SensorReading, Telemetry


def telem(drone: str = "drone01", **fields: Any) -> Telemetry:
    base: dict[str, Any] = dict(
        drone_id=drone, timestamp=0, armed=False, flight_mode="ready", landed_state="on_ground",
        battery=Battery(remaining_percent=0.9, voltage=12.1),
        position=Position(lat=40.6, lon=-8.6, alt=10.0, rel_alt=0.0),
    )
    base.update(fields)
    return Telemetry(**base)


def cmd_status(state: str, command: str = "takeoff", command_id: str = "c1", **fields: Any) -> CommandStatus:
    return CommandStatus(drone_id="drone01", timestamp=0, command_id=command_id, command=command, state=state, **fields)  # type: ignore[arg-type]


def lines(events: list[Any]) -> list[str]:
    return [f"{e.level.upper()} {e.message}" for e in events if isinstance(e, LogLine)]


def routed(registry: Registry, *drones: str) -> Registry:
    """The bus says a query from the ground finds these drones' command queryables."""
    for drone in drones or ("drone01", "drone02"):
        registry.on_route(drone, True, 0)
    return registry


@pytest.fixture
def reg() -> Registry:
    return routed(Registry(GroundConfig(sensor_timeout_ms={"temperature": 1000})))


def test_first_telemetry_registers_the_drone_ready(reg: Registry) -> None:
    events = reg.on_telemetry(telem(), 1000)
    assert lines(events) == ["INFO Registered", "INFO Established connection with ground station"]
    assert reg.info("drone01").state == "ready"
    assert any(isinstance(e, InfoChanged) for e in events)
    assert reg.on_telemetry(telem(), 1100) == []  # nothing changed, nothing said


def test_health_failure_on_the_ground_is_an_error_and_refuses_commands_but_return(reg: Registry) -> None:
    events = reg.on_telemetry(telem(health_failures=["accelerometer"]), 0)
    assert lines(events) == [
        "INFO Registered", "ERROR Failed health check: accelerometer", "INFO Established connection with ground station",
    ]
    assert reg.info("drone01").state == "error"
    refusal = reg.check_command("drone01", "arm")
    assert refusal is not None and refusal.status == 409 and "accelerometer" in refusal.reason
    assert reg.check_command("drone01", "return") is None
    assert lines(reg.on_telemetry(telem(), 100)) == ["INFO Errors cleared"]
    assert reg.check_command("drone01", "arm") is None
    # Just started, its landed state not yet known: not flying, so an error at once too
    # (a drone shown ready for that moment was assigned, then refused to arm).
    reg.on_telemetry(telem("drone02", landed_state="unknown", health_failures=["gyrometer"]), 0)
    assert reg.info("drone02").state == "error"


def test_in_flight_a_failing_health_check_warns_and_is_an_error_past_its_time(reg: Registry) -> None:
    """Issue 58: a flag that drops for a moment in flight is a warning; the drone is in
    error (and its mission fails) once it has stayed down health_error_after_s (5 s)."""
    flying: dict[str, Any] = {"armed": True, "landed_state": "in_air"}
    reg.on_telemetry(telem(**flying), 0)
    assert lines(reg.on_telemetry(telem(health_failures=["global_position"], **flying), 1000)) == [
        "WARN Health check failing: global_position"]
    assert reg.info("drone01").state == "hold"
    assert lines(reg.on_telemetry(telem(health_failures=["global_position"], **flying), 5900)) == []
    assert lines(reg.on_telemetry(telem(health_failures=["global_position"], **flying), 6000)) == [
        "ERROR Failed health check: global_position"]
    assert reg.info("drone01").state == "error"
    assert reg.check_command("drone01", "return") is None
    assert lines(reg.on_telemetry(telem(**flying), 6100)) == ["INFO Errors cleared"]


@given(st.lists(st.tuples(st.integers(1, 3000), st.booleans()), min_size=1, max_size=40))
def test_a_drone_is_in_error_exactly_when_its_health_has_failed_for_the_time_allowed(
        samples: list[tuple[int, bool]]) -> None:
    """Over random runs of samples (ms since the last, failing or not): error iff the
    current run of failing samples began health_error_after_s or more ago."""
    registry = routed(Registry(GroundConfig()))
    allowed_ms = GroundConfig().health_error_after_s * 1000
    now, since = 0, None
    for later, failing in samples:
        now += later
        registry.on_telemetry(telem(health_failures=["global_position"] if failing else [], armed=True,
                                    landed_state="in_air"), now)
        since = (now if since is None else since) if failing else None
        expected = "error" if since is not None and now - since >= allowed_ms else "hold"
        assert registry.info("drone01").state == expected, (now, since)


@pytest.mark.parametrize(
    ("battery", "state", "errors", "warns"),
    [(0.9, "ready", [], []), (0.15, "ready", [], ["Low battery level"]), (0.05, "error", ["Critical battery level"], [])],
)
def test_battery_thresholds(reg: Registry, battery: float, state: str, errors: list[str], warns: list[str]) -> None:
    reg.on_telemetry(telem(battery=Battery(remaining_percent=battery, voltage=11.0)), 0)
    info = reg.info("drone01")
    assert (info.state, info.errors, info.warns) == (state, errors, warns)


def test_command_life_cycle_sets_current_command_and_words_the_log(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    assert lines(reg.on_status(cmd_status("success", "arm", "a"), 10)) == ["INFO Success on arm"]
    reg.on_telemetry(telem(armed=True), 20)
    assert lines(reg.on_status(cmd_status("start", altitude=10.0), 30)) == ["INFO Start takeoff with altitude 10.0m"]
    info = reg.info("drone01")
    assert info.state == "active"
    assert info.current_command is not None and info.current_command.description == "Takeoff with altitude 10.0m"
    goto: dict[str, Any] = dict(command="goto", command_id="g1", coords=Coords(lat=40.634421, lon=-8.660437, alt=15.0))
    assert lines(reg.on_status(cmd_status("queued", **goto), 40)) == ["INFO Queued go to 40.634421, -8.660437 at 15.0m"]
    assert lines(reg.on_status(cmd_status("finish"), 50)) == ["INFO Finish takeoff"]
    assert lines(reg.on_status(cmd_status("start", **goto), 51)) == ["INFO Start go to 40.634421, -8.660437 at 15.0m"]
    assert reg.info("drone01").current_command.description == "Go to 40.634421, -8.660437 at 15.0m"  # type: ignore[union-attr]
    reg.on_telemetry(telem(armed=True, landed_state="in_air", flight_mode="hold"), 55)
    assert lines(reg.on_status(cmd_status("finish", command="goto", command_id="g1"), 60)) == [
        "INFO Finish go to 40.634421, -8.660437 at 15.0m"
    ]
    assert reg.info("drone01").state == "hold"
    reg.on_status(cmd_status("start", "land", "l1"), 70)
    assert lines(reg.on_status(cmd_status("cancel", "land", "l1"), 71)) == ["INFO Cancel land"]
    assert lines(reg.on_status(cmd_status("failure", "takeoff", "t2", reason="disarmed"), 80)) == [
        "WARN Failure on takeoff: disarmed"
    ]
    assert reg.on_status(
        SystemStatus(drone_id="drone01", timestamp=0, component="system", state="disarm"), 90
    )[0].message == "Auto disarmed"  # type: ignore[union-attr]


def test_manual_mode_refuses_commands(reg: Registry) -> None:
    reg.on_telemetry(telem(flight_mode="posctl"), 0)
    assert reg.info("drone01").state == "manual"
    refusal = reg.check_command("drone01", "takeoff")
    assert refusal is not None and refusal.reason == "drone is under manual control"


def test_unknown_drone_is_404(reg: Registry) -> None:
    refusal = reg.check_command("ghost", "return")
    assert refusal is not None and refusal.status == 404


def test_silence_past_the_timeout_makes_the_drone_unknown_until_telemetry_resumes(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    reg.on_status(cmd_status("start"), 10)
    assert reg.tick(5000) == []
    assert lines(reg.tick(5001)) == ["WARN Link lost: stopped receiving messages from drone"]
    info = reg.info("drone01")
    assert info.state == "unknown" and info.current_command is None
    assert reg.tick(9000) == []  # said once
    assert reg.check_command("drone01", "arm").status == 409  # type: ignore[union-attr]
    assert lines(reg.on_telemetry(telem(), 9100)) == ["INFO Link restored: established connection with ground station"]
    assert reg.info("drone01").state == "ready"


def test_liveliness_loss_is_unknown_at_once_and_late_samples_do_not_revive(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    reg.on_liveliness("drone01", True, 1)
    assert lines(reg.on_liveliness("drone01", False, 100)) == [
        "WARN Link lost: stopped receiving messages from drone (liveliness token lost)"
    ]
    assert reg.on_telemetry(telem(), 150) == []
    assert reg.info("drone01").state == "unknown"
    reg.on_liveliness("drone01", True, 2000)
    assert lines(reg.on_telemetry(telem(), 2100)) == ["INFO Link restored: established connection with ground station"]


def test_a_drone_heard_long_after_its_token_went_is_back_without_the_token(reg: Registry) -> None:
    # Seen in bench/mesh_stall.py: a link closed and reopened, telemetry flowed again, and
    # the ground's router never redelivered the token (upstream zenoh #2602's family).
    reg.on_telemetry(telem(), 0)
    reg.on_liveliness("drone01", True, 1)
    reg.on_liveliness("drone01", False, 100)
    assert reg.on_telemetry(telem(), 1100) == []  # within the grace: still a late sample
    assert lines(reg.on_telemetry(telem(), 1101)) == [
        "INFO Heard again without its liveliness token: telemetry decides its link until the token is back",
        "INFO Link restored: established connection with ground station",
    ]
    assert reg.info("drone01").state == "ready"
    # Without the token, silence is still found by the timeout.
    assert lines(reg.tick(1101 + 5001)) == ["WARN Link lost: stopped receiving messages from drone"]


def test_flight_controller_disconnect_is_a_warning(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    sys = SystemStatus(drone_id="drone01", timestamp=0, component="system", state="disconnect")
    assert lines(reg.on_status(sys, 1)) == ["WARN Flight controller system disconnected"]
    assert reg.info("drone01").warns == ["Flight controller disconnected"]
    reg.on_status(msgspec.structs.replace(sys, state="connect"), 2)
    assert reg.info("drone01").warns == []


def test_sensors_appear_with_their_first_reading_and_time_out_per_type(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    temp = SensorReading(drone_id="drone01", timestamp=0, type="temperature", value=21.5, unit="degC")
    cam = msgspec.structs.replace(temp, type="camera", value="frame.jpg", unit="")
    assert lines(reg.on_sensor(temp, 10)) == ["INFO Detected temperature sensor"]
    assert reg.on_sensor(temp, 20) == []
    reg.on_sensor(cam, 30)
    assert reg.info("drone01").sensors == ["camera", "temperature"]
    assert reg.select(sensors=["temperature", "camera"]) == ["drone01"]
    reg.on_telemetry(telem(), 1000)
    assert lines(reg.tick(1021)) == ["WARN Lost temperature sensor: no reading for 1000 ms"]
    assert reg.info("drone01").sensors == ["camera"]  # camera: timeout 0 = never
    assert reg.select(sensors=["temperature"]) == []


def test_mission_assignment_guards_commands(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    reg.assign("drone01", "m1", 1)
    assert reg.info("drone01").mission == "m1"
    assert reg.check_command("drone01", "arm").reason == "drone is assigned to mission m1"  # type: ignore[union-attr]
    assert reg.check_command("drone01", "arm", mission_id="m1") is None
    assert reg.check_command("drone01", "return") is None
    reg.release("drone01", 2)
    assert reg.check_command("drone01", "arm", mission_id="m1") is not None
    assert reg.check_command("drone01", "arm") is None


def test_a_finish_whose_start_was_not_heard_names_the_verb_alone(reg: Registry) -> None:
    reg.on_telemetry(telem(), 0)
    assert lines(reg.on_status(cmd_status("finish", command="move"), 10)) == ["INFO Finish move"]
    assert lines(reg.on_status(cmd_status("finish", command="return", command_id="c2"), 20)) == ["INFO Finish return to launch"]


def test_a_bundle_record_catches_the_ground_up_once_and_clears_the_stale_step(reg: Registry) -> None:
    """Statuses the drone published out of reach come back with its record: logged
    then, in order, and never twice (neither from a second read nor a late status)."""
    from dronefleet.schemas.bundles import BundleRecord, BundleStatus, StepEvent

    def status(step: int, state: str) -> BundleStatus:
        return BundleStatus(drone_id="drone01", timestamp=step, bundle_id="b3", step=step, state=state, steps=3)  # type: ignore[arg-type]

    reg.on_telemetry(telem(), 0)
    reg.note_bundle("drone01", "b3", ["Takeoff", "Wait 3 s", "Return to launch"])
    reg.on_status(status(0, "start"), 1)
    reg.on_status(status(0, "finish"), 2)
    reg.on_status(status(1, "start"), 3)
    assert reg.info("drone01").bundle is not None and reg.info("drone01").bundle.step == 1  # type: ignore[union-attr]
    # Out of reach: step 1 finishes, step 2 runs, the bundle is done; nothing heard.
    history = [StepEvent(step=s, state=st, timestamp=s) for s, st in  # type: ignore[arg-type]
               [(0, "start"), (0, "finish"), (1, "start"), (1, "finish"), (2, "start"), (2, "finish"), (2, "done")]]
    record = BundleRecord(bundle_id="b3", state="done", step=2, steps=3, steps_done=3, history=history)
    assert lines(reg.on_bundle_record(record, "drone01", 100)) == [
        "INFO Bundle b3: caught up on 4 events sent while out of reach",
        "INFO Bundle b3 step 3/3: Return to launch",
        "INFO Bundle b3 done (3 steps)",
    ]
    assert reg.info("drone01").bundle is None  # not stuck at step 2/3
    assert lines(reg.on_bundle_record(record, "drone01", 200)) == []
    assert lines(reg.on_status(status(2, "done"), 300)) == []  # the late status itself


def test_a_bundle_status_after_events_lost_out_of_reach_is_a_gap(reg: Registry) -> None:
    """The ground reads the record first when a bundle's status shows earlier events
    never arrived, so its log keeps the bundle's order (CI saw "done" logged before the
    steps it caught up on); statuses in order, or heard before, are no gap."""
    from dronefleet.schemas.bundles import BundleStatus

    def status(step: int, state: str, drone: str = "drone01") -> BundleStatus:
        return BundleStatus(drone_id=drone, timestamp=step, bundle_id="b3", step=step, state=state, steps=3)  # type: ignore[arg-type]

    reg.on_telemetry(telem(), 0)
    assert not reg.bundle_gap(status(0, "start"))
    reg.on_status(status(0, "start"), 1)
    assert not reg.bundle_gap(status(0, "finish"))
    assert not reg.bundle_gap(status(1, "start"))
    assert reg.bundle_gap(status(2, "start"))  # step 1 started out of reach
    assert reg.bundle_gap(status(1, "finish"))  # so did the step it ends
    assert reg.bundle_gap(status(2, "done"))
    reg.on_status(status(0, "finish"), 2)
    reg.on_status(status(1, "start"), 3)
    assert not reg.bundle_gap(status(1, "finish"))
    assert not reg.bundle_gap(status(1, "start"))  # a repeat
    assert not reg.bundle_gap(status(5, "done", drone="ghost"))  # not registered: nothing to order


def test_a_return_whose_end_was_never_heard_is_over_once_the_drone_is_landed_and_disarmed(reg: Registry) -> None:
    """Its `finish` was sent out of radio range: the drone would stay `active` for ever."""
    reg.on_telemetry(telem(armed=True, landed_state="in_air"), 0)
    reg.on_status(cmd_status("start", "return", "b-1/return", altitude=10.0), 10)
    reg.on_telemetry(telem(armed=True, landed_state="in_air"), 20)
    assert reg.info("drone01").state == "active"
    reg.on_telemetry(telem(armed=True, landed_state="on_ground"), 30)  # landed, not yet disarmed
    assert reg.info("drone01").state == "active"
    assert lines(reg.on_telemetry(telem(armed=False, landed_state="on_ground"), 40)) == [
        "INFO Finish return to launch with altitude 10.0m (landed)"]
    assert reg.info("drone01").state == "ready" and reg.info("drone01").current_command is None


def test_a_drone_heard_before_its_command_route_is_unreachable_until_the_route_comes(reg: Registry) -> None:
    fresh = Registry(GroundConfig())
    fresh.on_telemetry(telem(), 0)
    assert fresh.info("drone01").state == "unreachable"
    assert fresh.unrouted_for_ms("drone01", 400) == 400
    assert lines(fresh.tick(999)) == []  # a route usually follows within tenths of a second: nothing said yet
    assert lines(fresh.tick(1000)) == ["WARN Commands cannot reach it: heard, but no route here to its command "
                                       "queryable for 1.0 s"]
    events = fresh.on_route("drone01", True, 1500)
    assert lines(events) == ["INFO Commands reach it again after 1.5 s"]
    assert fresh.info("drone01").state == "ready" and fresh.unrouted_for_ms("drone01", 1600) is None


EVENTS = st.one_of(
    st.tuples(st.just("telem"), st.booleans()),  # in the air or not
    st.tuples(st.just("route"), st.booleans()),
    st.tuples(st.just("token"), st.booleans()),
    st.tuples(st.just("tick"), st.just(False)),
)


@given(st.lists(st.tuples(st.integers(0, 3000), EVENTS), min_size=1, max_size=60))
def test_a_drone_listed_commandable_always_has_a_route_and_a_lack_of_one_is_told_once(
        steps: list[tuple[int, tuple[str, bool]]]) -> None:
    """Over random interleavings of telemetry, route changes, tokens and time: a drone is
    ready, hold or active only while the bus says its command queryable is routed here;
    heard with none it is `unreachable`; the log says so once per outage, only after a
    second heard without one, and says when it is back only after saying it was gone."""
    registry = Registry(GroundConfig(drone_timeout_ms=60_000))
    now, routed, told = 0, False, False
    for later, (kind, value) in steps:
        now += later
        if kind == "telem":
            events = registry.on_telemetry(telem(armed=value, landed_state="in_air" if value else "on_ground"), now)
        elif kind == "route":
            routed = value
            events = registry.on_route("drone01", value, now)
        elif kind == "token":
            events = registry.on_liveliness("drone01", value, now)
        else:
            events = registry.tick(now)
        said = lines(events)
        if any("Commands cannot reach it" in line for line in said):
            assert not told and not routed
            told = True
        if any("Commands reach it again" in line for line in said):
            assert told and routed
            told = False
        if kind == "route" and value:
            assert not told, ("a route back after 'cannot reach' is said", steps)
        if "drone01" in registry:
            state = registry.info("drone01").state
            if state in ("ready", "hold", "active"):
                assert routed, (state, steps)
            if not routed and state != "unknown":
                assert state == "unreachable", (state, steps)


@given(st.integers(1, 5), st.lists(st.tuples(st.integers(0, 4000), st.integers(0, 9)), max_size=80))
def test_a_full_registry_keeps_its_drones_drops_new_ids_and_says_how_many_every_interval(
        cap: int, heard: list[tuple[int, int]]) -> None:
    """Over random streams of telemetry under ids 0-9 with room for `cap` drones: the
    first `cap` ids heard are registered and stay so, no other is, and every id turned
    away is counted in the next line that says so (at most one per 10 s)."""
    registry = Registry(GroundConfig(max_drones=cap, drone_timeout_ms=3_600_000))
    now, told_at = 0, None
    order: list[str] = []  # registered, in the order first heard
    dropped_since_line: set[str] = set()
    for later, n in heard:
        now += later
        drone_id = f"drone{n:02d}"
        registry.on_telemetry(telem(drone_id), now)
        if drone_id not in order and len(order) < cap:
            order.append(drone_id)
        elif drone_id not in order:
            dropped_since_line.add(drone_id)
        said = [e for e in registry.tick(now) if isinstance(e, LogLine) and "Registry full" in e.message]
        if said:
            assert told_at is None or now - told_at >= 10_000
            assert f": dropped the telemetry of {len(dropped_since_line)} drone id(s)" in said[0].message, said
            told_at, dropped_since_line = now, set()
        assert registry.ids() == sorted(order)


@given(st.floats(0, 50), st.lists(st.tuples(st.integers(0, 2000), st.integers(0, 400), st.booleans()), max_size=300))
def test_ids_that_never_said_what_they_are_register_only_from_the_bucket_and_are_counted(
        per_s: float, heard: list[tuple[int, int, bool]]) -> None:
    """Random telemetry under 401 ids, some of whose About came first: an announced id
    always registers; unannounced ones register at most UNANNOUNCED_BURST plus
    `unannounced_per_s` a second in all, and every one turned away is counted in the
    next line that says so."""
    registry = Registry(GroundConfig(unannounced_per_s=per_s, drone_timeout_ms=3_600_000))
    now, unannounced, dropped = 0, 0, set()
    for later, n, announced in heard:
        now += later
        drone_id = f"d{n}"
        if announced and registry.about(drone_id) is None and drone_id not in registry:
            registry.on_about(About(drone_id=drone_id, timestamp=now), now)
        known = drone_id in registry
        registry.on_telemetry(telem(drone_id), now)
        if registry.about(drone_id) is not None:
            assert drone_id in registry
        elif not known and drone_id in registry:
            unannounced += 1
        elif drone_id not in registry:
            dropped.add(drone_id)
        assert unannounced <= UNANNOUNCED_BURST + per_s * now / 1000 + 1e-9
        said = [e for e in registry.tick(now) if isinstance(e, LogLine) and "had not said what they are" in e.message]
        if said:
            assert f"Dropped the telemetry of {len(dropped)} new drone id(s)" in said[0].message, said
            dropped = set()


def test_abouts_of_ids_that_never_register_are_kept_for_the_newest_few_thousand_only() -> None:
    """An About flood under made-up ids (no telemetry follows) keeps the newest
    ABOUTS_UNREGISTERED_KEPT; one of them that then sends telemetry registers without the
    bucket, and a registered drone's About is never the one let go."""
    registry = Registry(GroundConfig(unannounced_per_s=0, drone_timeout_ms=3_600_000))
    registry.on_about(About(drone_id="real", timestamp=0), 0)
    registry.on_telemetry(telem("real"), 0)
    flood = ABOUTS_UNREGISTERED_KEPT + 500
    for i in range(flood):
        registry.on_about(About(drone_id=f"ghost{i}", timestamp=i), i)
    assert registry.about("ghost0") is None and registry.about(f"ghost{flood - 500}") is not None
    assert registry.about("real") is not None
    registry.on_telemetry(telem(f"ghost{flood - 1}"), flood)
    assert f"ghost{flood - 1}" in registry
