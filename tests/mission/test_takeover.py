"""What a ground does with a lost ground's missions (SPEC §14), at the stores: real
SQLite on both sides, alpha's numbered changes copied into bravo's store as the mesh
copies them. A mission whose journal never reached bravo cannot be run again: it ends
with cause `ground_lost`, saying why, and nothing of it is lost or taken twice."""

from __future__ import annotations

from pathlib import Path
from typing import cast

from dronefleet.bus.clock import VirtualClock
from dronefleet.mission.hosting.manager import MissionManager, MissionStore
from dronefleet.mission.lifecycle.fleet_port import GroundPort
from dronefleet.mission.lifecycle.record import MissionLogLine, MissionRecord
from dronefleet.schemas.fleet import WatchEvent


class Ground:
    """The station as a takeover with nothing to run uses it: what it broadcasts."""

    def __init__(self) -> None:
        self.events: list[WatchEvent] = []

    def broadcast(self, event: WatchEvent) -> None:
        self.events.append(event)

    def log_ground(self, level: str, message: str) -> None:
        raise AssertionError(f"nothing is taken over here, yet the ground logged {message!r}")


def copy_all(origin: MissionStore, into: MissionStore) -> int:
    """Every change of `origin` kept in `into` as alpha's; returns the last one's number."""
    keep = into.stream().keep
    for seq, entry in origin.stream().after(0, 10_000):
        keep("alpha", seq, entry)
    return origin.last_change()


def test_a_running_mission_whose_journal_never_came_ends_ground_lost_with_its_log_kept(tmp_path: Path) -> None:
    clock = VirtualClock()
    alpha = MissionStore(tmp_path / "alpha.db")
    bravo = MissionStore(tmp_path / "bravo.db")
    try:
        running = MissionRecord(mission_id="m1", name="survey", status="running", start=clock.time_ms(),
                                active_drones=["drone01"])
        alpha.create(running, "arm(assign('drone01'))")
        alpha.append("m1", MissionLogLine(timestamp=clock.time_ms(), level="info", message="Mission started"))
        finished = MissionRecord(mission_id="m2", status="finished", cause="success")
        alpha.create(finished, "pass")
        upto = copy_all(alpha, bravo)
        ground = Ground()
        manager = MissionManager(cast(GroundPort, ground), bravo, clock, isolate=True)

        (taken,) = manager.take_over("alpha", upto)

        assert (taken.mission_id, taken.status, taken.cause) == ("alpha-m1", "failed", "ground_lost")
        assert "journal of mission m1 did not reach this ground" in (taken.message or ""), taken.message
        assert taken.active_drones == []
        assert bravo.get("alpha-m1") == taken
        assert bravo.source("alpha-m1") == ""
        log = [line.message for line in manager.log("alpha-m1")]
        assert log[0] == "Mission started" and log[-1].startswith("Mission failed: ground_lost"), log
        assert [e.data["mission_id"] for e in ground.events if e.kind == "mission"] == ["alpha-m1"]
        assert bravo.get("alpha-m2") is None  # an ended mission is not taken over
        assert manager.take_over("alpha", upto) == []  # nor one taken already
    finally:
        alpha.close()
        bravo.close()
