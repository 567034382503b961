"""Which ground is active (SPEC §14, ground/active_ground.py), as properties over random
sets of grounds and random orders of what each hears: exactly one active ground among
those that may command, the one the rule chooses; and after a partition in which each
side chose its own, one again, holding the newest epoch."""

from __future__ import annotations

import random

import msgspec
from hypothesis import given, settings
from hypothesis import strategies as st

from dronefleet.ground.active_ground import Change, Standing, chosen
from dronefleet.schemas.grounds import ActiveGround, GroundInfo

grounds = st.lists(
    st.builds(GroundInfo, ground_id=st.sampled_from("abcdefgh"), priority=st.integers(-2, 2),
              role=st.sampled_from(["ground", "ground", "observer"])),
    min_size=1, max_size=6, unique_by=lambda g: g.ground_id,
)


class Mesh:
    """Grounds that hear each other's tokens and active publications, delivered in an
    order a seed draws; `links` says who hears whom (a partition: two groups)."""

    def __init__(self, infos: list[GroundInfo], seed: int) -> None:
        self.rng = random.Random(seed)
        self.standing = {g.ground_id: Standing(g) for g in infos}
        self.links = {a: set(self.standing) - {a} for a in self.standing}
        self.queue: list[tuple[str, str, object]] = []  # (to, kind, what)
        self.time = 0

    def heard(self, to: str, changes: list[Change]) -> None:
        for change in changes:
            if change.state == "active":
                self.say_active(to)

    def say_active(self, ground_id: str) -> None:
        s = self.standing[ground_id]
        self.time += 1
        for other in self.links[ground_id]:
            self.queue.append((other, "active", ActiveGround(ground_id=ground_id, epoch=s.epoch, timestamp=self.time)))

    def settle(self) -> None:
        for _ in range(10_000):
            if not self.queue:
                return
            to, kind, what = self.queue.pop(self.rng.randrange(len(self.queue)))
            s = self.standing[to]
            if kind == "token":
                assert isinstance(what, GroundInfo)
                self.heard(to, s.heard_ground(self.info(what.ground_id) if what.ground_id in self.standing else what))
            elif kind == "gone":
                assert isinstance(what, str)
                self.heard(to, s.lost_ground(what))
            elif kind == "start":
                self.heard(to, s.start())
            elif kind == "ask":
                assert isinstance(what, str)
                other = self.standing[what]
                if other.active and what in self.links[to]:
                    self.heard(to, s.heard_active(ActiveGround(ground_id=what, epoch=other.epoch, timestamp=self.time)))
            else:
                assert isinstance(what, ActiveGround)
                self.heard(to, s.heard_active(what))
        raise AssertionError("the grounds never settled")

    def info(self, ground_id: str) -> GroundInfo:
        """What a ground answers about itself now: the highest epoch it heard included."""
        s = self.standing[ground_id]
        return msgspec.structs.replace(s.me, epoch_seen=s.highest_epoch, epoch_held=s.epoch)

    def connect(self, a: str, b: str) -> None:
        self.links[a].add(b)
        self.links[b].add(a)
        self.queue += [(a, "token", self.info(b)), (b, "token", self.info(a))]
        # Each asks the other whether it is active, answered when the question arrives:
        # a ground that stepped down meanwhile says nothing.
        self.queue += [(a, "ask", b), (b, "ask", a)]

    def cut(self, a: str, b: str) -> None:
        self.links[a].discard(b)
        self.links[b].discard(a)
        self.queue += [(a, "gone", b), (b, "gone", a)]

    def start_all(self) -> None:
        """Every ground starts and hears every other's token, in the seed's order."""
        for a in self.standing:
            self.queue.append((a, "start", None))
            self.queue += [(a, "token", self.standing[b].me) for b in self.standing if b != a]
        self.settle()

    def actives(self) -> list[str]:
        return [g for g, s in self.standing.items() if s.active]


@settings(max_examples=300, deadline=None)
@given(infos=grounds, seed=st.integers(0, 2**32))
def test_grounds_that_hear_each_other_agree_on_one_active_the_rule_chooses(infos: list[GroundInfo], seed: int) -> None:
    mesh = Mesh(infos, seed)
    mesh.start_all()
    want = chosen(infos)
    assert mesh.actives() == ([want] if want else [])
    if want:
        epoch = mesh.standing[want].epoch
        assert epoch >= 1 and all(s.highest_epoch <= epoch for s in mesh.standing.values())
        assert all(s.active_id == want for s in mesh.standing.values())


@settings(max_examples=300, deadline=None)
@given(infos=grounds.filter(lambda gs: sum(g.role == "ground" for g in gs) >= 2), seed=st.integers(0, 2**32),
       split=st.integers(1, 5))
def test_after_a_partition_heals_one_ground_is_active_with_the_newest_epoch(
        infos: list[GroundInfo], seed: int, split: int) -> None:
    """Cut in two, each side elects its own active ground (two actives, no agent obeys
    both: the epochs differ or the older is fenced); healed, one is left, and its epoch
    is above every epoch any ground took or heard."""
    mesh = Mesh(infos, seed)
    ids = list(mesh.standing)
    mesh.start_all()
    left, right = ids[: split % len(ids) or 1], ids[split % len(ids) or 1:]
    for a in left:
        for b in right:
            mesh.cut(a, b)
    mesh.settle()
    for a in left:
        for b in right:
            mesh.connect(a, b)
    mesh.settle()
    want = chosen(infos)
    assert want is not None and mesh.actives() == [want]
    epoch = mesh.standing[want].epoch
    assert all(s.highest_epoch <= epoch for s in mesh.standing.values())
    assert all(s.epoch < epoch for g, s in mesh.standing.items() if g != want)

    # One ground restarts (it remembers nothing: alone, it takes epoch 1) and joins again.
    again = ids[seed % len(ids)]
    for other in ids:
        if other != again:
            mesh.cut(again, other)
    mesh.settle()
    mesh.standing[again] = Standing(mesh.standing[again].me)
    mesh.queue.append((again, "start", None))
    mesh.settle()
    for other in ids:
        if other != again:
            mesh.connect(again, other)
    mesh.settle()
    assert mesh.actives() == [want]
    newest = mesh.standing[want].epoch
    assert all(s.highest_epoch <= newest for s in mesh.standing.values())
    assert all(s.epoch < newest for g, s in mesh.standing.items() if g != want)


def test_observers_never_command_and_a_lone_ground_is_active_with_epoch_1() -> None:
    alone = Standing(GroundInfo(ground_id="laptop"))
    assert alone.start() == [Change("active", 1, "started")] and alone.active
    watcher = Standing(GroundInfo(ground_id="a", priority=99, role="observer"))
    assert watcher.start() == [] and not watcher.active
    assert watcher.heard_ground(GroundInfo(ground_id="z")) == [] and not watcher.active
    assert watcher.active_id == "z"
