"""The mission sandbox against known Python sandbox escapes (issue 5).

Each escape must be refused at submit (ScriptError, with line and column) or fail
its mission with cause `security` at run time — and none may leave its mark (a file
written in tmp_path). Run-time cases execute as real missions in a fast-time field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from dronefleet.compose import SimField
from dronefleet.mission.script.sandbox import Guards, ScriptError, check_mission, compile_mission
from dronefleet.sim.world import World

MARK = "MARKFILE"

# (name, script): MARKFILE is replaced by a path the escape would write to.
STATIC = [
    ("import os", "import os\nos.system('touch MARKFILE')"),
    ("from os import system", "from os import system\nsystem('touch MARKFILE')"),
    ("import subprocess", "import subprocess\nsubprocess.run(['touch', 'MARKFILE'])"),
    ("import sys", "import sys\nsys.modules['os'].system('touch MARKFILE')"),
    ("import builtins", "import builtins\nbuiltins.open('MARKFILE', 'w')"),
    ("import socket", "import socket\nsocket.socket()"),
    ("importlib", "import importlib\nimportlib.import_module('os')"),
    ("relative import", "from . import x"),
    ("star import", "from math import *"),
    ("open", "open('MARKFILE', 'w').write('x')"),
    ("exec", "exec(\"open('MARKFILE','w')\")"),
    ("eval", "eval('1')"),
    ("compile", "compile('1', 'x', 'eval')"),
    ("__import__", "__import__('os').system('touch MARKFILE')"),
    ("globals", "globals()['__builtins__']"),
    ("locals", "locals()"),
    ("vars", "vars()"),
    ("dir", "dir()"),
    ("breakpoint", "breakpoint()"),
    ("subclasses walk", "[].__class__.__base__.__subclasses__()"),
    ("mro walk", "().__class__.mro()[-1]"),
    ("function globals", "def f(): pass\nf.__globals__['__builtins__']"),
    ("func_globals", "def f(): pass\nf.func_globals"),
    ("generator frame", "g = (x for x in [1])\ng.gi_frame.f_globals"),
    ("frame back", "def f(): pass\nf.gi_frame"),
    ("traceback frame", "try:\n    1/0\nexcept Exception as e:\n    e.__traceback__.tb_frame.f_globals"),
    ("tb_frame", "try:\n    1/0\nexcept Exception as e:\n    t = e.with_traceback(None)"),
    ("str.format attribute walk", "'{0.__class__.__base__}'.format(1)"),
    ("format_map", "'{x}'.format_map({'x': 1})"),
    ("type() class factory", "type('X', (), {})"),
    ("object", "object.__subclasses__()"),
    ("super", "super()"),
    ("metaclass", "class M(metaclass=list): pass"),
    ("bare except swallowing cancel", "try:\n    pass\nexcept:\n    pass"),
    ("BaseException catch", "try:\n    pass\nexcept BaseException:\n    pass"),
    ("private name", "_fleet_tick = None"),
    ("dunder def", "class A:\n    def __getattr__(self, n): pass"),
    ("async def", "async def f():\n    pass"),
    ("code object", "def f(): pass\nf.__code__.co_code"),
    ("builtins name", "__builtins__['open']('MARKFILE', 'w')"),
    ("setattr", "setattr(1, 'x', 2)"),
    ("match class private attr", "match 1:\n    case int(__class__=x):\n        pass"),
]

RUNTIME = [
    ("getattr dunder by string", "getattr(1, '__cl' + 'ass__')"),
    ("getattr frame by string", "g = (x for x in [1])\ngetattr(g, 'gi_' + 'frame')"),
    ("hasattr probe", "hasattr(1, '_' + '_class__')"),
    ("getattr format", "getattr('{0.__class__}', 'for' + 'mat')(1)"),
    ("statistics leaks sys", "import statistics\ngetattr(statistics, 'sy' + 's').modules['os'].system('touch MARKFILE')"),
    ("functools.reduce getattr chain", "import functools\nfunctools.reduce(getattr, ['__class__', '__base__'], 1)"),
    ("random internals", "import random\ngetattr(random, '_' + 'os').system('touch MARKFILE')"),
    ("subclasses by string", "b = getattr(getattr(1, '__cl' + 'ass__'), '__ba' + 'se__')\n"
     "w = [c for c in getattr(b, '__subcl' + 'asses__')() if getattr(c, '__na' + 'me__') == '_wrap_close'][0]\n"
     "getattr(getattr(w, '__in' + 'it__'), '__glo' + 'bals__')['system']('touch MARKFILE')"),
    ("pow bomb", "x = 10 ** 10 ** 10"),
    ("lshift bomb", "x = 1 << 10 ** 12"),
    ("sequence bomb", "x = 'a' * 10 ** 12"),
    ("augmented bomb", "x = 'a'\nx *= 10 ** 12"),
    ("dynamic import name", "m = 'o' + 's'\nimport math\n[getattr(math, '_' + '_loader__')]"),
]


def test_corpus_is_large_enough() -> None:
    assert len(STATIC) + len(RUNTIME) >= 30


@pytest.mark.parametrize(("name", "script"), STATIC, ids=[n for n, _ in STATIC])
def test_static_escapes_are_refused_with_line_and_column(name: str, script: str, tmp_path: Path) -> None:
    with pytest.raises(ScriptError) as info:
        compile_mission(script.replace(MARK, str(tmp_path / "mark")))
    assert info.value.line is not None and info.value.line >= 1
    assert info.value.column is not None and info.value.column >= 1
    assert info.value.kind == "security"


async def test_runtime_escapes_fail_the_mission_with_cause_security(tmp_path: Path) -> None:
    mark = tmp_path / "mark"
    # Escapes that leave the mark when run as plain Python (checked when they were written).
    assert sum(MARK in script for _, script in RUNTIME) >= 3
    field = SimField(World(), 1)
    await field.start()
    try:
        for name, template in RUNTIME:
            script = template.replace(MARK, str(mark))
            compile_mission(script)  # passes the static check: only run time can refuse it
            record = await field.run_mission(script, name=name, max_s=30)
            assert (record.status, record.cause) == ("failed", "security"), (name, record)
            assert "line " in (record.message or ""), (name, record.message)
            assert not mark.exists(), name
    finally:
        await field.close()


def test_syntax_error_names_line_and_column() -> None:
    with pytest.raises(ScriptError) as info:
        compile_mission("x = 1\nif x\n    pass\n")
    assert (info.value.kind, info.value.line) == ("syntax", 2)
    assert info.value.column == 5


@pytest.mark.parametrize("source", ["return", "x = 1\nbreak", "yield 3", "def f():\n    nonlocal y\n"])
def test_what_only_the_compiler_refuses_is_a_syntax_error_with_its_line(source: str) -> None:
    """Found by the API fuzz test: `POST /mission` with `return` answered 500."""
    (problem,) = check_mission(source)
    assert problem.kind == "syntax" and problem.line == source.count("\n", 0, len(source.rstrip("\n"))) + 1
    with pytest.raises(ScriptError):
        compile_mission(source)


def test_check_lists_every_problem_in_order() -> None:
    problems = check_mission("import os\nx = 1\nopen('f')\ny.__class__\n")
    assert [(p.line, p.column) for p in problems] == [(1, 1), (3, 1), (4, 1)]


def test_ordinary_python_is_accepted() -> None:
    compile_mission(
        "import math, random, statistics, itertools, functools, collections\n"
        "from collections import deque\n"
        "def f(a, *rest, k=1, **kw):\n    return [x * 2 for x in range(a) if x % 2]\n"
        "class Box:\n    pass\n"
        "for _ in range(3):\n    pass\n"
        "try:\n    1 / 0\nexcept ZeroDivisionError as e:\n    print(f'{e!r:>10}')\n"
        "print(format(math.pi, '.2f'), statistics.mean([1, 2]), sorted({3, 1}))\n"
    )


def test_random_in_a_script_draws_from_the_missions_seed_alone() -> None:
    """`random.random()` and `getrandbits()` (C methods) come from the mission's seeded
    generator as `uniform()` does: they once drew from the process's, so a replay or a
    simulation with the same seed read other numbers."""

    def draws(seed: int) -> list[float]:
        load: Any = Guards(lambda: None, lambda line: None, seed).builtins()["__import__"]
        module = load("random")
        return [module.random(), module.getrandbits(16), module.uniform(0, 1), module.random()]

    assert draws(7) == draws(7)
    assert draws(7) != draws(8)
