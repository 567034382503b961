"""How long a fleet is without a ground that commands when the active one dies, and what
it costs that a running mission survives it (SPEC §14, ADR 0017).

Each run starts two real `fleet ground` processes (alpha, priority 10, active; bravo
joining alpha's router, standby) and three `fleet agent --fc sim` connected to both,
submits to alpha a two-drone mission with two subroutines and a channel (four legs
each: tests/ground/test_durable_missions.py's), waits until the first leg is under way and
kills alpha with SIGKILL (no goodbye: a laptop whose battery died). Then:
- takeover: from the kill to bravo accepting a command for the third drone (the lease
  that notices alpha gone, the election, the new epoch reaching the agent, the round
  trip);
- the mission must finish on bravo (`alpha-m1`, cause success);
- journal: the bytes of alpha's journal in bravo's copy per command verb it holds an
  answer to, and the milliseconds bravo's worker took to take that journal again per
  such verb (its log line).

    .venv/bin/python bench/takeover.py [--runs 20] [--bar-s 5]

Prints one line per run and p50/max; exits 1 if a run took longer than the bar (issue
55: the standby is active within 5 s) or a mission did not finish on bravo.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import re
import sqlite3
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dronefleet.mission.hosting import worker  # noqa: E402
from dronefleet.mission.hosting.journal import Entry  # noqa: E402
from tests.ground.test_durable_missions import SCRIPT, SPAWNS  # noqa: E402
from tests.harness import ended, stop_all, submit, two_grounds_and_fleet, wait_state  # noqa: E402
from tests.waiting import until  # noqa: E402

_entries = msgspec.msgpack.Decoder(list[Entry])
_to_worker = msgspec.msgpack.Decoder(worker.ToWorker)


@dataclass
class Run:
    takeover_s: float
    journal_bytes: int
    verbs: int  # command verbs answered in the journal
    replay_ms: float


def journal_of(db: Path, origin: str, mission_id: str) -> tuple[int, int]:
    """Bytes of a copied mission's journal entries, and the command answers among them."""
    size = verbs = 0
    with sqlite3.connect(db) as con:
        for (body,) in con.execute("SELECT body FROM mission_copies WHERE origin = ? AND mission_id = ? AND "
                                   "kind = 'entries' ORDER BY seq", (origin, mission_id)):
            for entry in _entries.decode(base64.b64decode(body)):
                size += len(entry.frame) + 9  # the frame and its time (msgpack float64)
                frame = _to_worker.decode(entry.frame)
                verbs += isinstance(frame, worker.Reply) and bool(frame.result)  # an assign's answer is empty
    return size, verbs


async def one_takeover(tmp: Path) -> Run:
    alpha, bravo, agents = two_grounds_and_fleet(tmp, SPAWNS, max_speed=6)
    try:
        await alpha.ready()
        await bravo.ready()
        async with httpx.AsyncClient(base_url=alpha.url, timeout=5) as a, \
                httpx.AsyncClient(base_url=bravo.url, timeout=5) as b:
            for drone_id in SPAWNS:
                await wait_state(b, drone_id, "ready", 30)

            async def alpha_active() -> bool:
                listed = {g["ground_id"]: g for g in (await b.get("/ground")).json()}
                return listed.get("alpha", {}).get("active") is True and listed.get("bravo", {}).get("active") is False
            await until(alpha_active, 20, "bravo standby, alpha active")
            mission_id = await submit(a, SCRIPT, "takeover")

            async def first_leg() -> bool:  # under way
                lanes = (await a.get(f"/mission/{mission_id}")).json().get("subroutines", [])
                return any(x.get("verb") == "move" for x in lanes)
            await until(first_leg, 60, "the scout's first leg")
            killed = time.monotonic()
            alpha.kill()

            async def accepted() -> bool:
                return (await b.post("/drone/drone03/cmd", json={"cmd": "arm"})).status_code == 200
            await until(accepted, 30, "bravo accepting a command after alpha died")
            took = time.monotonic() - killed
            taken = f"alpha-{mission_id}"
            done = await ended(b, taken, 120)
            if (done["status"], done["cause"]) != ("finished", "success"):
                raise SystemExit(f"{taken} ended {done['status']} ({done['cause']}): {done['message']}")
            log = [line["message"] for line in (await b.get(f"/mission/{taken}")).json()["log"]]
            said = next((m for m in log if m.startswith("Journal taken again")), "")
            found = re.search(r"in (\d+) ms", said)
            size, verbs = journal_of(bravo.data_dir / "missions.db", "alpha", mission_id)
            return Run(took, size, verbs, float(found.group(1)) if found else float("nan"))
    finally:
        stop_all([*agents, bravo, alpha])


async def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--bar-s", type=float, default=5.0, help="the longest takeover allowed")
    args = parser.parse_args()
    runs: list[Run] = []
    for n in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="takeover-") as tmp:
            runs.append(r := await one_takeover(Path(tmp)))
        print(f"run {n + 1}: bravo commanded {r.takeover_s:.2f} s after alpha was killed; the mission finished there; "
              f"journal {r.journal_bytes} B for {r.verbs} verbs, taken again in {r.replay_ms:.0f} ms", flush=True)
    times = [r.takeover_s for r in runs]
    per_verb_b = [r.journal_bytes / r.verbs for r in runs if r.verbs]
    per_verb_ms = [r.replay_ms / r.verbs for r in runs if r.verbs]
    over = [t for t in times if t > args.bar_s]
    print(f"takeover (SIGKILL of the active ground to the standby's first accepted command), {len(times)} runs: "
          f"p50 {statistics.median(times):.2f} s, max {max(times):.2f} s; {len(over)} over {args.bar_s:g} s")
    if per_verb_b:
        print(f"journal per command verb: p50 {statistics.median(per_verb_b):.0f} B (max {max(per_verb_b):.0f}); "
              f"taken again in p50 {statistics.median(per_verb_ms):.1f} ms (max {max(per_verb_ms):.1f})")
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
