"""A mission's journal runs it again to the same point (ADR 0017), as a property over
random fleets: telemetry of two drones arriving at random times with random values,
a script whose subroutines branch on what they read, sleep random times, talk through a
channel and command a drone. The real worker (`mission.hosting.worker.serve`) runs the
real mission against an in-process ground on a socket pair; then a second worker takes
a random prefix of the first one's journal again. What the replay would have sent —
every call with its command id, every log line with its time, every record — is the
first run's, in order, up to where the prefix ends."""

from __future__ import annotations

import asyncio
import json
import socket
import time
import uuid
from typing import Any

import msgspec
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dronefleet.mission.hosting import worker
from dronefleet.mission.hosting.journal import Entry
from dronefleet.mission.lifecycle.record import MissionRecord
from dronefleet.schemas.codec import encode
from dronefleet.schemas.commands import CommandReply
from dronefleet.schemas.config_loading import MissionSettings
from dronefleet.schemas.fleet import DroneInfo
from dronefleet.schemas.status import CommandStatus
from dronefleet.schemas.telemetry import Position, Telemetry

DRONES = ("drone01", "drone02")
SCRIPT = '''import random

d1, d2 = assign("drone01", "drone02")

def watch(d, name, rounds):
    seen = []
    for k in range(rounds):
        wait(d)
        alt = round(d.position.alt, 1)
        seen.append(alt)
        if alt > 50:
            print(name, "high", k, alt)
        sleep(random.random() / 20 * s)
    if name == "a":
        channel.a = sum(seen)
    else:
        channel.b = sum(seen)

def act(d):
    first = channel.a
    arm(d)
    print("armed after", first)
    disarm(d)

a = run(watch, d1, "a", 3)
b = run(watch, d2, "b", 2)
c = run(act, d1)
wait(a, b, c)
print("end", round(channel.a + channel.b, 1))
'''
_to_ground = msgspec.msgpack.Decoder(worker.ToGround)


def info(drone_id: str) -> bytes:
    return msgspec.json.encode(DroneInfo(drone_id=drone_id, state="ready", current_command=None, sensors=[],
                                         mission=None, errors=[], warns=[]))


def telemetry(drone_id: str, alt: float, armed: bool = False) -> bytes:
    return encode(Telemetry(drone_id=drone_id, timestamp=int(time.time() * 1000), armed=armed,
                            position=Position(lat=40.6334, lon=-8.6608, alt=alt, rel_alt=alt - 8.0)))


def start_of(seed: int) -> worker.Start:
    snapshot = [worker.Event(kind, body) for d in DRONES
                for kind, body in (("drone", info(d)), ("telemetry", telemetry(d, 10.0)))]
    return worker.Start(record=MissionRecord(mission_id="m1"), source=SCRIPT, settings=MissionSettings(), plugins=[],
                        enable=None, snapshot=snapshot, relays=None, uid=str(uuid.UUID(int=seed)),
                        started_ms=int(time.time() * 1000), seed=seed)


class Ground:
    """The ground's side of one worker: answers its calls (a command at once, then the
    drone's success and telemetry that shows it done), feeds it telemetry, keeps what
    it sent and its journal."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.sent: list[Any] = []  # what the mission sent, journal entries aside
        self.entries: list[Entry] = []
        self.marks: list[int] = []  # len(sent) when each entry came: what the mission had sent before taking it
        self.done = asyncio.Event()
        self.resumed = asyncio.Event()  # a replaying worker has taken its journal
        self.armed = False

    def send(self, message: Any) -> None:
        if not self.writer.is_closing():
            self.writer.write(worker.frame(message))

    async def serve(self) -> None:
        while (body := await worker.read_frame(self.reader)) is not None:
            message = _to_ground.decode(body)
            if isinstance(message, worker.Journalled):
                self.marks.append(len(self.sent))
                self.entries.append(message.entry)
                continue
            if isinstance(message, worker.Ack):
                continue
            self.sent.append(message)
            if isinstance(message, worker.Done):
                self.done.set()
            elif isinstance(message, worker.Resumed):
                self.resumed.set()
            elif isinstance(message, worker.Call):
                self.answer(message)

    def answer(self, call: worker.Call) -> None:
        if call.op != "command":
            self.send(worker.Reply(call=call.call))
            return
        body = json.loads(call.arg)
        self.send(worker.Reply(call=call.call, result=msgspec.json.encode(
            CommandReply(command_id=body["command_id"], accepted=True))))
        self.armed = body["cmd"] == "arm"
        self.send(worker.Event("status", msgspec.json.encode(CommandStatus(
            drone_id=call.drone_id, timestamp=int(time.time() * 1000), command_id=body["command_id"],
            command=body["cmd"], state="success"))))
        self.send(worker.Event("telemetry", telemetry(call.drone_id, 10.0, armed=self.armed)))

    async def feed(self, plan: list[tuple[float, int, float]]) -> None:
        for pause_s, drone, alt in plan:
            await asyncio.sleep(pause_s)
            self.send(worker.Event("telemetry", telemetry(DRONES[drone], alt, armed=self.armed)))
        while not self.done.is_set():  # the rest at a steady pace until the script has read its fill
            await asyncio.sleep(0.02)
            for d in DRONES:
                self.send(worker.Event("telemetry", telemetry(d, 10.0, armed=self.armed)))


async def run(start: worker.Start, plan: list[tuple[float, int, float]] | None,
              replayed: list[Any]) -> Ground:
    """One worker to its end (plan: live, fed from it) or through its journal (None).
    The worker gets its Start as its process would, decoded from its bytes (the mission
    changes its record as it goes)."""
    start = msgspec.msgpack.decode(msgspec.msgpack.encode(start), type=worker.Start)
    ours, theirs = socket.socketpair()
    w_reader, w_writer = await asyncio.open_unix_connection(sock=theirs)
    g_reader, g_writer = await asyncio.open_unix_connection(sock=ours)
    ground = Ground(g_reader, g_writer)
    serving = asyncio.ensure_future(ground.serve())
    mission = asyncio.ensure_future(worker.serve(w_reader, w_writer, start,
                                                 replayed=lambda m: replayed.append(msgspec.msgpack.encode(m))))
    feeding = asyncio.ensure_future(ground.feed(plan)) if plan is not None else None
    try:
        if plan is not None:
            async with asyncio.timeout(30):
                await ground.done.wait()
        else:  # the journal taken again; then the ground goes
            resumed = asyncio.ensure_future(ground.resumed.wait())
            try:
                async with asyncio.timeout(30):
                    await asyncio.wait([mission, resumed], return_when=asyncio.FIRST_COMPLETED)
            finally:
                resumed.cancel()
    finally:
        g_writer.close()
        for task in (feeding, serving):
            if task is not None:
                task.cancel()
        async with asyncio.timeout(10):
            await asyncio.gather(mission, return_exceptions=True)
        await asyncio.gather(*(t for t in (feeding, serving) if t is not None), return_exceptions=True)
        w_writer.close()
    return ground


@settings(max_examples=25, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(seed=st.integers(1, 2**31), plan=st.lists(st.tuples(st.floats(0, 0.03), st.integers(0, 1), st.floats(0, 100)),
                                                  min_size=0, max_size=12),
       cut=st.floats(0, 1))
def test_a_prefix_of_the_journal_runs_the_mission_again_to_that_point(seed: int, plan: list[tuple[float, int, float]],
                                                                       cut: float) -> None:
    start = start_of(seed)

    async def both() -> tuple[Ground, Ground, list[Any], int]:
        first = await run(start, plan, [])
        assert isinstance(first.sent[-1], worker.Done) and first.sent[-1].record.status == "finished", first.sent[-1]
        k = round(cut * len(first.entries))
        again: list[Any] = []
        second = await run(msgspec.structs.replace(start, journal=first.entries[:k]), None, again)
        return first, second, again, k

    first, second, again, k = asyncio.run(both())
    live = [msgspec.msgpack.encode(m) for m in first.sent if not isinstance(m, worker.Done)]
    # Nothing the replay makes differs from the first run, to the byte (command ids, log
    # times), and it gets at least as far as the first run had when it journalled the
    # last entry taken again (sleepers due after it are the live run's to wake).
    assert again == live[:len(again)]
    if k:
        assert len(again) >= first.marks[k - 1], (len(again), first.marks[k - 1])
    # What the replay wrote goes to the ground when it goes live: the ground keeps the
    # log lines its copy lacks, and the subroutines' lanes.
    (resumed,) = [m for m in second.sent if isinstance(m, worker.Resumed)]
    wrote = [_to_ground.decode(m) for m in again]
    assert resumed.log == [m.line for m in wrote if isinstance(m, worker.Logged)]
    assert resumed.activities == [m.activity for m in wrote if isinstance(m, worker.Active)]
