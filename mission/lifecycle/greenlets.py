"""Blocking-style mission code on the ground's asyncio loop: greenlets bridged to tasks.

Every subroutine of a mission (the script itself included) is a greenlet driven by
one asyncio task. A verb calls `await_(awaitable)`: the greenlet switches back to
its driver task, which awaits the awaitable on the loop and switches back in with
the result — SQLAlchemy's `await_only` pattern. Nothing runs in parallel, so mission
state needs no locks, and under a VirtualClock the interleaving is a function of the
script and the seed alone.

A script that computes without calling verbs still passes `tick()` (the sandbox puts
one at the top of every loop and function body): after a slice of work it yields to
the loop, so telemetry, HTTP and other missions keep running, and once its mission
is stopping it raises `Stopped`, which scripts cannot catch. See
docs/adr/0001-mission-runtime.md for the choice and its limits.
"""

from __future__ import annotations

import asyncio
import contextvars
import itertools
import time
from collections.abc import Awaitable, Callable
from typing import Any, Literal, TypeVar

from greenlet import getcurrent, greenlet

T = TypeVar("T")
SLICE_S = 0.01  # real time a script may compute before yielding to the loop
SLICE_TICKS = 2000  # the same in ticks, used under a virtual clock (deterministic)


_CURRENT: contextvars.ContextVar[Subroutine | None] = contextvars.ContextVar("subroutine", default=None)


def current_subroutine() -> Subroutine | None:
    """The subroutine running now: its script greenlet, or its driver task (or a task
    that one started), if any."""
    sub: Subroutine | None = getattr(getcurrent(), "sub", None)
    return sub if sub is not None else _CURRENT.get()


class Stopped(BaseException):
    """Raised inside a subroutine that is being stopped; scripts cannot catch it."""


class _ScriptGreenlet(greenlet):
    sub: Subroutine


class Subroutine:
    """The handle `run()` returns: `.running`, `.finished`, `.result`."""

    __slots__ = ("_error", "_result", "_stopping", "_task", "_done", "daemon", "name", "owner", "parent", "plugin", "sid")

    def __init__(self, owner: Scheduler, name: str, daemon: bool = False, plugin: str | None = None,
                 sid: str = "", parent: Subroutine | None = None) -> None:
        self.owner = owner
        self.name = name
        self.sid = sid  # s0, s1, …: in the order the mission's subroutines started
        self.parent = parent
        self.daemon = daemon  # a plugin's monitor: the mission does not wait for it
        self.plugin = plugin  # the monitoring plugin that started it (or an ancestor), if any
        self._task: asyncio.Task[Any] | None = None
        self._stopping = False
        self._result: Any = None
        self._error: BaseException | None = None
        self._done = asyncio.get_running_loop().create_future()

    @property
    def running(self) -> bool:
        return not self._done.done()

    @property
    def finished(self) -> bool:
        return self._done.done()

    @property
    def result(self) -> Any:
        return self._result

    @property
    def outcome(self) -> Literal["failed", "stopped", "finished"]:
        """How it ended (or is ending): an exception escaped it, it was stopped, or it ran out."""
        return "failed" if self._error is not None else "stopped" if self._stopping else "finished"

    async def ended(self) -> None:
        """Until the subroutine has ended (at once if it has)."""
        await asyncio.shield(self._done)

    def finish(self) -> None:
        """Mark the subroutine ended (once: its driver or its task's end, whichever first)."""
        if not self._done.done():
            self._done.set_result(None)
            self.owner.on_activity("ended", self)

    def __repr__(self) -> str:
        return f"<subroutine {self.name} {'running' if self.running else 'finished'}>"


class Scheduler:
    """The subroutines of one mission.

    `on_error(sub, exc)` hears of every exception that escapes a subroutine (other than
    its being stopped); the mission decides what it means.
    """

    def __init__(self, on_error: Callable[[Subroutine, BaseException], None], *, deterministic: bool) -> None:
        self._on_error = on_error
        self._deterministic = deterministic
        self._names = itertools.count()
        self.subroutines: list[Subroutine] = []
        # hears each subroutine `started` and `ended` (the mission's activity, /events)
        self.on_activity: Callable[[str, Subroutine], None] = lambda event, sub: None
        self.stopping = False
        self._slice_start = time.perf_counter()
        self._ticks = 0

    # ---- starting and stopping ----------------------------------------------------

    def spawn(self, fn: Callable[..., Any], *args: Any, name: str | None = None, daemon: bool = False,
              plugin: str | None = None) -> Subroutine:
        """Start `fn(*args)` as a subroutine; one started by a plugin's subroutine
        belongs to that plugin too (`plugin`)."""
        parent = current_subroutine()
        if plugin is None:
            plugin = parent.plugin if parent is not None else None
        sid = f"s{len(self.subroutines)}"
        sub = Subroutine(self, name or f"sub{next(self._names)}", daemon, plugin, sid, parent)
        self.subroutines.append(sub)
        self.on_activity("started", sub)
        sub._task = asyncio.get_running_loop().create_task(self._drive(sub, fn, args), name=sub.name)
        # A task cancelled before its first step never runs _drive's `finally`: the
        # subroutine must still finish (a survey stopped right after it was started).
        sub._task.add_done_callback(lambda _: sub.finish())
        if self.stopping:
            sub._stopping = True
        return sub

    def stop(self, sub: Subroutine) -> None:
        """Ask one subroutine to stop: it raises Stopped at its next verb or tick."""
        if sub.running and not sub._stopping:
            sub._stopping = True
            assert sub._task is not None
            sub._task.cancel()

    def stop_all(self) -> None:
        self.stopping = True
        for sub in list(self.subroutines):
            self.stop(sub)

    async def join_all(self, timeout_s: float) -> bool:
        """Wait for every subroutine (also ones started meanwhile) to end; True if they did."""
        deadline = asyncio.get_running_loop().time() + timeout_s
        while True:
            pending = [s._done for s in self.subroutines if s.running]
            if not pending:
                return True
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                return False
            await asyncio.wait(pending, timeout=remaining)

    async def wait_idle(self) -> None:
        """Wait until no subroutine runs (the script and everything it started),
        plugin monitors aside."""
        while True:
            pending = [s._done for s in self.subroutines if s.running and not s.daemon]
            if not pending:
                return
            await asyncio.wait(pending)

    # ---- the bridge ---------------------------------------------------------------

    async def _drive(self, sub: Subroutine, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        _CURRENT.set(sub)  # this task's own context (and that of the tasks it starts)
        g = _ScriptGreenlet(fn)
        g.sub = sub
        try:
            value = g.switch(*args)
            while not g.dead:
                try:
                    result = await value
                except asyncio.CancelledError:
                    sub._stopping = True
                    value = g.throw(Stopped())
                except BaseException as exc:
                    value = g.throw(exc)
                else:
                    value = g.switch(result)
            sub._result = value
        except (Stopped, asyncio.CancelledError):
            pass
        except BaseException as exc:  # noqa: BLE001 - reported to the mission, never lost
            sub._error = exc
            self._on_error(sub, exc)
        finally:
            sub.finish()
            if not g.dead:  # the task itself was torn down: unwind the script's frames
                try:
                    g.throw(Stopped())
                except BaseException:  # noqa: BLE001
                    pass

    def tick(self) -> None:
        """The checkpoint in every loop and function of a script."""
        current = getcurrent()
        sub = getattr(current, "sub", None)
        if sub is None:
            return
        if sub._stopping:
            raise Stopped()
        self._ticks += 1
        if self._deterministic:
            due = self._ticks >= SLICE_TICKS
        else:
            due = self._ticks % 64 == 0 and time.perf_counter() - self._slice_start >= SLICE_S
        if due:
            await_(asyncio.sleep(0))

    def note_switch(self) -> None:
        self._ticks = 0
        self._slice_start = time.perf_counter()


def await_(awaitable: Awaitable[T]) -> T:
    """Block the calling script greenlet until `awaitable` is done on the loop."""
    current = getcurrent()
    sub: Subroutine | None = getattr(current, "sub", None)
    if sub is None:
        raise RuntimeError("await_ called outside a mission subroutine")
    if sub._stopping:
        if asyncio.iscoroutine(awaitable):
            awaitable.close()
        raise Stopped()
    result = current.parent.switch(awaitable)
    sub.owner.note_switch()
    return result
