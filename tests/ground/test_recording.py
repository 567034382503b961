"""Recordings (SPEC §12): what is written, that standard readers read it and every
message fits its schema, that a killed recorder's file is readable, that a replay
gives a fresh ground the registry of the original, and that fast time records the
same bytes for the same seed."""

from __future__ import annotations

import asyncio
import json
import signal
from collections import Counter
from pathlib import Path
from typing import Any

import httpx
import jsonschema_rs
import msgspec
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from dronefleet.bus.clock import VirtualClock
from dronefleet.bus.memory import MemoryBus, MemoryNetwork
from dronefleet.bus.recording import FLUSH_S, Liveliness, Recorder, Replay, read, recover
from dronefleet.cli import main
from dronefleet.compose import simulate
from dronefleet.schemas.codec import encode
from dronefleet.schemas.telemetry import Position, Telemetry
from dronefleet.sim.world import load_world
from tests.harness import ChildProcess, GroundFleet, GroundProcess, fleet_command, stop_all
from tests.waiting import until

EXAMPLES = Path(__file__).parents[2] / "examples"


def checked_messages(path: Path) -> Counter[str]:
    """Read `path` with the mcap package's own reader; every message must be JSON that
    its channel's schema accepts. Returns the count of messages per schema."""
    kinds: Counter[str] = Counter()
    validators: dict[int, Any] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "a complete file has a summary"
        last = 0
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json"
            assert schema is not None, f"{channel.topic} has no schema"
            assert schema.encoding == "jsonschema" and schema.name.startswith("fleet.")
            if schema.id not in validators:
                validators[schema.id] = jsonschema_rs.validator_for(json.loads(schema.data))
            body = json.loads(message.data)
            errors = [str(e) for e in validators[schema.id].iter_errors(body)]
            assert not errors, (channel.topic, body, errors)
            assert message.log_time >= last, "log time is receive time: it never goes back"
            last = message.log_time
            kinds[schema.name.removeprefix("fleet.")] += 1
        assert sum(kinds.values()) == summary.statistics.message_count
    return kinds


def telemetry(drone_id: str, lat: float, t_ms: int) -> bytes:
    return encode(Telemetry(drone_id=drone_id, timestamp=t_ms, armed=False,
                            position=Position(lat=lat, lon=-8.66, alt=10.0, rel_alt=0.0)))


# ---- fast time ---------------------------------------------------------------------


async def test_simulate_records_the_mission_and_the_same_seed_records_the_same_bytes(tmp_path: Path) -> None:
    source = (EXAMPLES / "two_drones.py").read_text()
    world = load_world(None)
    first, second = tmp_path / "first", tmp_path / "second"
    for out in (first, second):
        result = await simulate(source, world, n=2, seed=3, out_dir=out, plots=False)
        assert result["mission"]["status"] == "finished"
    assert (first / "recording.mcap").read_bytes() == (second / "recording.mcap").read_bytes()

    kinds = checked_messages(first / "recording.mcap")
    assert kinds["Telemetry"] >= 40 and kinds["Status"] >= 8 and kinds["Liveliness"] >= 3, kinds
    assert kinds["Command"] == 8, kinds  # arm, takeoff, move, land for each drone
    contents = read(first / "recording.mcap")
    assert contents.complete and contents.metadata["mission_id"] == "m1"
    records = [json.loads(m.data) for m in contents.messages if m.kind == "MissionRecord"]
    assert [r["status"] for r in records][-1] == "finished"
    telemetry_topics = {m.topic for m in contents.messages if m.kind == "Telemetry"}
    assert telemetry_topics == {"drone/drone01/telem", "drone/drone02/telem"}


def test_fleet_plot_draws_a_recording_and_a_result_and_refuses_anything_else(tmp_path: Path) -> None:
    runner = CliRunner()
    sim = runner.invoke(main, ["mission", "simulate", str(EXAMPLES / "two_drones.py"), "--drones", "2",
                               "--out", str(tmp_path / "run")])
    assert sim.exit_code == 0, sim.output
    for name in ("recording.mcap", "result.json"):
        out = tmp_path / f"plots-{name}"
        drawn = runner.invoke(main, ["plot", str(tmp_path / "run" / name), "--out", str(out)])
        assert drawn.exit_code == 0, drawn.output
        assert sorted(p.name for p in out.iterdir()) == [
            "altitude.png", "battery.png", "distances.png", "link.png", "paths.png"]
        assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in out.iterdir())
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a recording at all")
    refused = runner.invoke(main, ["plot", str(junk)])
    assert refused.exit_code == 2 and "not an MCAP recording" in refused.output, refused.output


def test_a_recording_cut_short_is_read_up_to_its_last_chunk_and_recovered(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    recorder = Recorder(path)
    t0 = 1_700_000_000_000_000_000
    for i in range(30):  # 3 s of log time at 10 Hz: chunks close at 1 s and 2 s
        recorder.write("drone/d1/telem", telemetry("d1", 40.0 + i * 1e-5, t0 // 1_000_000 + i * 100), t0 + i * 100_000_000)
    cut = path.read_bytes()  # what a recorder killed now leaves: no summary, no footer
    recorder.close()
    (tmp_path / "killed.mcap").write_bytes(cut)

    contents = read(tmp_path / "killed.mcap")
    assert not contents.complete
    flushed = int(2 * FLUSH_S * 10) + 1  # every message up to the second flush
    assert len(contents.messages) == flushed, len(contents.messages)
    assert [m.log_ns for m in contents.messages] == [t0 + i * 100_000_000 for i in range(flushed)]

    result = CliRunner().invoke(main, ["record", "--recover", str(tmp_path / "killed.mcap"), "--out", str(tmp_path / "fixed.mcap")])
    assert result.exit_code == 0 and f"{flushed} messages" in result.output and "cut short" in result.output, result.output
    assert checked_messages(tmp_path / "fixed.mcap") == {"Telemetry": flushed}
    assert read(path).complete and len(read(path).messages) == 30


async def test_a_replay_keeps_timing_and_liveliness_and_never_sends_commands(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    recorder = Recorder(path)
    t0 = 1_700_000_000_000_000_000
    recorder.write_struct("drone/d1/alive", Liveliness(True), t0, "Liveliness")
    recorder.write("drone/d1/telem", telemetry("d1", 40.0, 0), t0 + 1_000_000_000)
    recorder.write("drone/d1/cmd", b'{"cmd":"land","drone_id":"d1"}', t0 + 1_500_000_000)
    recorder.write("drone/d1/telem", telemetry("d1", 40.1, 2000), t0 + 3_000_000_000)
    recorder.write_struct("drone/d1/alive", Liveliness(False), t0 + 4_000_000_000, "Liveliness")
    recorder.close()

    clock = VirtualClock()
    network = MemoryNetwork()
    bus, watcher = MemoryBus(network, "replay"), MemoryBus(network, "ground")
    heard: list[tuple[float, str]] = []
    watcher.subscribe("**", lambda s: heard.append((clock.monotonic(), s.key)))
    watcher.watch_liveliness("**", lambda key, alive: heard.append((clock.monotonic(), f"{key} {alive}")))
    commanded: list[bytes] = []

    async def refuse(key: str, payload: bytes) -> bytes:
        commanded.append(payload)
        return b"{}"

    watcher.serve("drone/d1/cmd", refuse)
    player = Replay(bus, read(path), clock, speed=2.0)
    task = asyncio.ensure_future(player.run())
    for _ in range(30):
        await clock.advance(0.1)
    await task
    assert heard == [(0.0, "drone/d1/alive True"), (0.5, "drone/d1/telem"), (1.5, "drone/d1/telem"),
                     (2.0, "drone/d1/alive False")], heard
    assert commanded == [] and player.published == 4
    await bus.close()
    await watcher.close()


# ---- real processes ------------------------------------------------------------------

MISSION = """
drone = assign("drone01")
arm(drone)
takeoff(drone, alt=4)
move(drone, forward=6 * meters)
"""


def comparable(view: dict[str, Any]) -> dict[str, Any]:
    """What a replay must reproduce of a drone in the registry (not the ground's clock)."""
    info = dict(view["info"])
    info.pop("link")  # measured every second: compared with the recording's last word instead
    for about in ("kind", "roles", "sensors_declared"):  # About goes out at the agent's start, before
        info.pop(about, None)  # `fleet record` began: not in this recording (the live ground asked the agent)
    current = info.pop("current_command", None)
    info["current_command"] = current and {k: v for k, v in current.items() if k != "timestamp"}
    return {"info": info, "telem": view["telem"]}


@pytest.mark.integration
@pytest.mark.slow(12)
async def test_record_a_sim_flight_then_replay_it_into_a_fresh_ground(tmp_path: Path) -> None:
    """`fleet record` beside a ground flying a mission; Ctrl-C leaves a valid file; the
    ground's own mission recording holds the commands; `fleet replay` gives a fresh
    ground the same registry; a killed recorder's file is readable."""
    fleet = GroundFleet(tmp_path, {"drone01": "sim://?lat=40.6334&lon=-8.660815&alt=8.2",
                                   "drone02": "sim://?lat=40.6334&lon=-8.66069&alt=8.2"})
    out, killed = tmp_path / "flight.mcap", tmp_path / "killed.mcap"
    started: list[ChildProcess] = []

    def child(name: str, *args: str) -> ChildProcess:
        started.append(ChildProcess(fleet_command(*args), tmp_path / f"{name}.log"))
        return started[-1]

    try:
        async with fleet.client() as http:
            recorder = child("record", "record", "--connect", fleet.ground.endpoint, "--out", str(out))
            victim = child("killed", "record", "--connect", fleet.ground.endpoint, "--out", str(killed))

            def heard_both() -> bool:
                topics = {m.topic for m in read(out).messages} if out.exists() and out.stat().st_size > 0 else set()
                return {"drone/drone01/telem", "drone/drone02/telem"} <= topics

            await until(heard_both, 30, "the recorder writing both drones' telemetry")
            response = await http.post("/mission", content=MISSION.encode(), params={"name": "recorded"})
            assert response.status_code == 201, response.text
            mission_id = response.json()["mission_id"]

            async def ended() -> bool:
                return (await http.get(f"/mission/{mission_id}")).json()["end"] is not None

            await until(ended, 90, "the mission's end")
            finished = (await http.get(f"/mission/{mission_id}")).json()
            assert finished["status"] == "finished", finished
            victim.kill()
            original = {d: comparable((await http.get(f"/drone/{d}")).json()) for d in ("drone01", "drone02")}
            assert original["drone01"]["telem"]["position"]["rel_alt"] > 3.5
            assert recorder.stop(signal.SIGINT) == 0, recorder.output()
            # The registry as it was when the recorder stopped (drones hover, telemetry moves on):
            # compare it with the recording's last word on each drone.
            recorded = read(out)
            assert recorded.complete, "Ctrl-C closes the file"
            kinds = checked_messages(out)
            assert kinds["Telemetry"] > 20 and kinds["Status"] >= 4 and kinds["Liveliness"] >= 3, kinds
            assert "Command" not in kinds, "commands are queries: a subscriber does not see them"

            ground_recording = fleet.ground.data_dir / "missions" / f"{mission_id}.mcap"
            mission_kinds = checked_messages(ground_recording)
            assert mission_kinds["Command"] == 3 and mission_kinds["MissionRecord"] >= 2, mission_kinds
            commands = [json.loads(m.data)["cmd"] for m in read(ground_recording).messages if m.kind == "Command"]
            assert commands == ["arm", "takeoff", "goto"], commands  # `move` goes out as a goto

        cut = read(killed)
        assert not cut.complete and any(m.kind == "Telemetry" for m in cut.messages), len(cut.messages)

        last_telem, last_link = {}, {}
        for message in recorded.messages:
            body = json.loads(message.data)
            if message.kind == "Telemetry":
                last_telem[body["drone_id"]] = body
            elif message.kind == "LinkQuality" and body["peer"] == "ground":  # what the registry keeps
                last_link[body["drone_id"]] = body
        fleet.stop()  # the original drones leave the mesh; only the replay speaks now

        (tmp_path / "fresh").mkdir()
        fresh = GroundProcess(tmp_path / "fresh")
        started.append(fresh)
        await fresh.ready()
        player = child("replay", "replay", str(out), "--connect", fresh.endpoint, "--speed", "8", "--hold")
        async with httpx.AsyncClient(base_url=fresh.url, timeout=10) as http:
            async def replayed() -> bool:
                assert player.proc is not None and player.proc.poll() is None, player.output()
                views = (await http.get("/drone")).json()
                return {v["info"]["drone_id"] for v in views} == {"drone01", "drone02"} and all(
                    v["telem"] == last_telem[v["info"]["drone_id"]] and v["info"]["link"] == last_link[v["info"]["drone_id"]]
                    for v in views)

            await until(replayed, 60, "the fresh ground's registry at the recording's end")
            await until(lambda: "holding" in player.output(), 30, "the replay's end")
            again = {d: comparable((await http.get(f"/drone/{d}")).json()) for d in ("drone01", "drone02")}
        for drone_id in ("drone01", "drone02"):
            # Replayed, a drone is heard but has no agent to command: unreachable (issue 76)
            assert again[drone_id]["info"] == original[drone_id]["info"] | {"mission": None, "state": "unreachable"}, drone_id
            assert again[drone_id]["telem"] == last_telem[drone_id]
    finally:
        try:
            stop_all(reversed(started))  # every one, also when one will not stop
        finally:
            fleet.stop()


async def test_a_recorder_that_joins_a_running_recording_is_told_which_tokens_are_alive(tmp_path: Path) -> None:
    """The ground's second concurrent mission shares the first one's subscription."""
    from dronefleet.bus.recording import BusRecording

    network = MemoryNetwork()
    bus, drone = MemoryBus(network, "ground"), MemoryBus(network, "drone01")
    first, late = Recorder(tmp_path / "first.mcap"), Recorder(tmp_path / "late.mcap")
    recording = BusRecording(bus, [first], now_ns=lambda: 1_700_000_000_000_000_000)
    drone.announce("drone/drone01/alive")
    await until(lambda: first.messages == 1, 5, "the token recorded")
    recording.add(late)
    drone.publish("drone/drone01/telem", telemetry("drone01", 40.0, 0))
    await until(lambda: late.messages == 2, 5, "the telemetry recorded by both")
    recording.close()
    for path in (first, late):
        assert [(m.topic, m.kind) for m in read(path.path).messages] == [  # type: ignore[arg-type]
            ("drone/drone01/alive", "Liveliness"), ("drone/drone01/telem", "Telemetry")]
    await drone.close()
    await bus.close()


async def test_overlapping_key_expressions_record_each_message_once(tmp_path: Path) -> None:
    """`fleet record 'drone/**' 'drone/drone01/**'`: a message under both is one message."""
    from dronefleet.bus.recording import BusRecording

    network = MemoryNetwork()
    bus, drone = MemoryBus(network, "ground"), MemoryBus(network, "drone01")
    recorder = Recorder(tmp_path / "overlap.mcap")
    recording = BusRecording(bus, [recorder], ["drone/**", "drone/drone01/**", "drone/*/telem", "ground/**"],
                             now_ns=lambda: 1_700_000_000_000_000_000)
    drone.announce("drone/drone01/alive")
    drone.publish("drone/drone01/telem", telemetry("drone01", 40.0, 0))
    drone.publish("ground/status", b"{}")
    drone.publish("other/key", b"{}")  # under none of them
    await until(lambda: recorder.messages >= 3, 5, "three messages recorded")
    drone.publish("drone/drone02/telem", telemetry("drone02", 40.0, 0))
    await until(lambda: recorder.messages >= 4, 5, "the fourth")
    recording.close()
    assert Counter(m.topic for m in read(recorder.path).messages) == Counter(  # type: ignore[arg-type]
        {"drone/drone01/alive": 1, "drone/drone01/telem": 1, "ground/status": 1, "drone/drone02/telem": 1})
    await drone.close()
    await bus.close()


def test_recover_keeps_kinds_beyond_the_mesh(tmp_path: Path) -> None:
    """A ground's recording holds mission records, which the mesh's kinds do not name:
    `fleet record --recover` used to fail on them with a KeyError (issue 31)."""

    class Note(msgspec.Struct):
        text: str

    src, dst = tmp_path / "ground.mcap", tmp_path / "recovered.mcap"
    recorder = Recorder(src, kinds={"Note": Note})
    recorder.write("ground/note", b'{"text": "kept"}', 1_000, "Note")
    recorder.close()
    recover(src, dst)
    again = read(dst)
    assert [(m.topic, m.kind, m.data) for m in again.messages] == [("ground/note", "Note", b'{"text": "kept"}')]
    assert again.schemas["Note"] == read(src).schemas["Note"]
