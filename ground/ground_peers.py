"""This ground among the grounds on one mesh (SPEC §14): its liveliness token
`ground/<ground_id>` and what it says of itself (`ground/<id>/info`), the others as they
come and go, and, while it is the active one, its epoch on `ground/<id>/active` (at once
on taking over, then every ANNOUNCE_S, and to a query). Which ground is active is
decided by `ground/active_ground.py`; this module only carries it over the mesh.

With no other ground configured (`connect`) a ground decides at once: alone on the mesh
it is active with epoch 1 and all of this is invisible. With `connect` it listens
LISTEN_S first, so it does not take over from a ground already active.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from pathlib import Path

import msgspec

from dronefleet.bus.clock import Clock
from dronefleet.bus.port import Bus, BusError, Declaration, NoRoute, Sample
from dronefleet.ground.active_ground import Change, Standing
from dronefleet.schemas.grounds import RESERVED, ActiveGround, GroundInfo
from dronefleet.schemas.keys import Keys

log = logging.getLogger(__name__)

LISTEN_S = 1.5  # how long a starting ground listens for the others before it decides
ASK_S = 2.0  # … and waits at most for what the grounds it heard say of themselves
ASK_TRIES = 12  # a ground whose queryable has not reached this router yet is asked again (about 8 s in all)
ANNOUNCE_S = 2.0  # the active ground says so this often
_info = msgspec.json.Decoder(GroundInfo)
_active = msgspec.json.Decoder(ActiveGround)


class GroundPeers:
    def __init__(self, bus: Bus, keys: Keys, me: GroundInfo, clock: Clock,
                 on_change: Callable[[Change], None] = lambda change: None, epoch_file: Path | None = None,
                 streams: Callable[[], dict[str, int]] = dict,
                 on_active: Callable[[ActiveGround], None] = lambda said: None) -> None:
        """`epoch_file` keeps the highest epoch across restarts (a ground back alone never
        takes an epoch another ground already used)."""
        self.bus = bus
        self.keys = keys
        self._epoch_file = epoch_file
        self._streams = streams
        self._on_active_said = on_active
        self.standing = Standing(me, remembered_epoch=_read_epoch(epoch_file))
        self.clock = clock
        self._on_change = on_change
        self._asking: dict[str, asyncio.Task[None]] = {}  # grounds being asked what they are

    @property
    def me(self) -> GroundInfo:
        return self.standing.me

    @property
    def active(self) -> bool:
        return self.standing.active

    @property
    def epoch(self) -> int:
        """The epoch this ground's commands carry: its own while active (0 before it decided)."""
        return self.standing.epoch

    def active_ground(self) -> GroundInfo | None:
        """The active ground as far as this one knows (None: none yet)."""
        active_id = self.standing.active_id
        return None if active_id is None else self.standing.heard.get(active_id, GroundInfo(ground_id=active_id))

    def heard_epoch(self, epoch: int, where: str) -> None:
        self._apply(self.standing.heard_epoch(epoch, where))

    def listing(self) -> list[dict[str, object]]:
        """`GET /ground`: every ground heard, its role, the epoch it said it holds, and
        which is this one (`this`: the dashboard says whether it shows a standby)."""
        s = self.standing
        return [{**{k: v for k, v in msgspec.structs.asdict(g).items() if not k.startswith("epoch_")},
                 "active": g.ground_id == s.active_id, "this": g.ground_id == s.me.ground_id,
                 "epoch": s.epoch if g.ground_id == s.me.ground_id else s.epochs.get(g.ground_id, 0)}
                for g in sorted(s.heard.values(), key=lambda g: g.ground_id)]

    def declare(self) -> list[Declaration]:
        me, k = self.me.ground_id, self.keys
        return [
            self.bus.serve(k.ground(me, "info"), self._answer_info),
            self.bus.serve(k.ground(me, "active"), self._answer_active),
            self.bus.subscribe(k.ground("*", "active"), self._on_active),
            self.bus.watch_liveliness(k.ground("*"), self._on_token),
            self.bus.announce(k.ground(me)),
        ]

    async def run(self, listen_first: bool) -> None:
        """Decide (after listening LISTEN_S for the others, when there may be some), then
        say so every ANNOUNCE_S while active."""
        if listen_first:
            await self.clock.sleep(LISTEN_S)
            if self._asking:  # grounds heard but not yet asked what they are: their answers first
                await asyncio.wait(list(self._asking.values()), timeout=ASK_S)
        self._apply(self.standing.start())
        while True:
            if self.active:
                self._publish()
            await self.clock.sleep(ANNOUNCE_S)

    def close(self) -> None:
        for task in list(self._asking.values()):
            task.cancel()

    # ---- the mesh in ----------------------------------------------------------------

    async def _answer_info(self, key: str, payload: bytes) -> bytes:
        s = self.standing
        return msgspec.json.encode(msgspec.structs.replace(self.me, epoch_seen=s.highest_epoch, epoch_held=s.epoch))

    async def _answer_active(self, key: str, payload: bytes) -> bytes:
        return msgspec.json.encode(self._said()) if self.active else b"{}"

    def _on_token(self, key: str, alive: bool) -> None:
        ground_id = key.rsplit("/", 1)[-1]
        if ground_id in RESERVED or ground_id == self.me.ground_id:
            return
        if not alive:
            self._apply(self.standing.lost_ground(ground_id))
            return
        self._ask(ground_id)

    def _ask(self, ground_id: str) -> None:
        if ground_id in self._asking:
            return
        task = asyncio.get_running_loop().create_task(self._ask_info(ground_id), name=f"ground {ground_id} info")
        self._asking[ground_id] = task
        task.add_done_callback(lambda _: self._asking.pop(ground_id, None))

    async def _ask_info(self, ground_id: str) -> None:
        """What a ground that appeared says of itself (a reply it could not make in
        time counts with defaults), then its epoch if it is the active one.

        A token that no queryable of its ground ever stands behind is not a ground: a
        ground serves `info` before it declares its token, so once the mesh has had time
        to route to it (ASK_TRIES), nobody there means a token the routers kept or put
        back after its ground was lost. Zenoh 1.x routers do that: a token declaration
        from a router that has just left the link-state graph is registered anyway
        ("Error propagating token …: cannot get index of …", zenoh's hat/router/token.rs)
        and never withdrawn. Counted, such a ghost would win the rule by its id and
        make the active ground stand down (ADR 0016). It counts once it speaks (an
        announcement of `ground/<id>/active`) or its token comes again."""
        info = GroundInfo(ground_id=ground_id)
        pause_s = 0.1
        for _ in range(ASK_TRIES):  # its token can cross the mesh before its queryable does
            try:
                info = _info.decode(await self.bus.query(self.keys.ground(ground_id, "info"), timeout_s=ASK_S))
                break
            except NoRoute:
                await self.clock.sleep(pause_s)
                pause_s = min(2 * pause_s, 1.0)
            except (BusError, msgspec.MsgspecError) as exc:
                log.warning("ground %s did not say what it is (%s): counted as priority 0", ground_id, exc)
                break
        else:
            log.warning("ground %s: its token is on the mesh but nothing answers for it after %d tries: not counted "
                        "(a token kept after its ground was lost)", ground_id, ASK_TRIES)
            return
        self._apply(self.standing.heard_ground(info))
        try:  # and its epoch, if it is active: not only at its next announcement
            said = await self.bus.query(self.keys.ground(ground_id, "active"), timeout_s=2.0)
            if said.strip() != b"{}":
                self._apply(self.standing.heard_active(_active.decode(said)))
        except (BusError, msgspec.MsgspecError) as exc:
            log.info("ground %s did not say whether it is active (%s): its next announcement will", ground_id, exc)

    def _on_active(self, sample: Sample) -> None:
        try:
            said = _active.decode(sample.payload)
        except msgspec.MsgspecError:
            return
        if said.ground_id not in self.standing.heard and said.ground_id != self.me.ground_id:
            self._ask(said.ground_id)  # heard before its token: what is it?
        self._apply(self.standing.heard_active(said))
        if said.ground_id != self.me.ground_id:
            self._on_active_said(said)

    # ---- the mesh out ---------------------------------------------------------------

    def _said(self) -> ActiveGround:
        return ActiveGround(ground_id=self.me.ground_id, epoch=self.epoch, timestamp=self.clock.time_ms(),
                            streams=self._streams())

    def _publish(self) -> None:
        self.bus.publish(self.keys.ground(self.me.ground_id, "active"), msgspec.json.encode(self._said()))

    def _apply(self, changes: list[Change]) -> None:
        for change in changes:
            if change.state == "active":
                _write_epoch(self._epoch_file, change.epoch)
                self._publish()
            self._on_change(change)


def _read_epoch(path: Path | None) -> int:
    try:
        return int(path.read_text().strip()) if path is not None else 0
    except (OSError, ValueError):
        return 0


def _write_epoch(path: Path | None, epoch: int) -> None:
    if path is None:
        return
    scratch = path.with_suffix(".tmp")
    scratch.write_text(f"{epoch}\n")
    scratch.replace(path)  # whole or not at all
