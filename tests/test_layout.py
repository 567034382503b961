"""The house (issue 33, SPEC §1): one top-level import package whose rooms are the
folders at the root of the repository; no import circles among its modules (imports
inside functions count, `if TYPE_CHECKING:` ones do not). Files are split where
concepts separate, not at a line count (issue 56). The layers themselves are import-linter's contracts (pyproject.toml)."""

from __future__ import annotations

import ast
import importlib
import io
import subprocess
import sys
import tokenize
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
ROOMS = ("agent", "bus", "examples", "ground", "mission", "relay", "schemas", "sim")


def test_every_room_at_the_root_is_a_subpackage_of_dronefleet() -> None:
    for room in ROOMS:
        module = importlib.import_module(f"dronefleet.{room}")
        assert module.__file__ is not None
        assert Path(module.__file__).resolve() == ROOT / room / "__init__.py", room
        assert (ROOT / "dronefleet" / room).resolve() == ROOT / room, f"dronefleet/{room} must link to ../{room}"


def _cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph.modules):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.find_modules_directly_imported_by(start))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.find_modules_directly_imported_by(child)))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_no_import_circles() -> None:
    graph = grimp.build_graph("dronefleet", exclude_type_checking_imports=True, cache_dir=None)
    assert len(graph.modules) > 100  # the rooms were walked through their links
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_circle() -> None:
    graph = grimp.ImportGraph()
    for module in ("p", "p.a", "p.b", "p.c"):
        graph.add_module(module)
    graph.add_import(importer="p.a", imported="p.b")
    graph.add_import(importer="p.b", imported="p.c")
    graph.add_import(importer="p.c", imported="p.a")
    assert _cycles(graph) == [["p.a", "p.b", "p.c"]]


def test_lint_fails_a_room_imported_under_its_own_name() -> None:
    """Inside the checkout `import agent` works (the folder is at the root); installed,
    it does not. `make lint` (ruff's banned imports, pyproject.toml) refuses it anywhere
    in the repository, mission scripts included; the package's own name passes."""
    lines = [f"from {room}.x import y\nimport {room}\n" for room in ROOMS]
    for where in ("agent/new.py", "tests/test_new.py", "examples/new_mission.py", "mission/bundled/new.py"):
        for room, source in zip(ROOMS, lines, strict=True):
            found = _ruff(source, where)
            assert found.count(f"TID251 `{room}` is banned") == 2, (where, found)
        assert _ruff(f"from dronefleet.{ROOMS[0]} import runtime\n", where) == ""


def _ruff(source: str, filename: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--select", "TID251", "--output-format", "concise", "--quiet",
         "--stdin-filename", str(ROOT / filename), "-"],
        input=source, capture_output=True, text=True, cwd=ROOT, timeout=60,
    )
    assert done.returncode in (0, 1), done.stderr
    return done.stdout


def our_classes_patched(source: str) -> list[str]:
    """`monkeypatch.setattr(X, ...)` where X (or its root name) is imported from dronefleet
    (tests add a seam instead: a fault, a lossy link, a plugin's public hook)."""
    tree = ast.parse(source)
    ours: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("dronefleet"):
            ours.update(alias.asname or alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            ours.update((alias.asname or alias.name).split(".")[0] for alias in node.names if alias.name.startswith("dronefleet"))
    found = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in ("setattr", "delattr")
                and isinstance(node.func.value, ast.Name) and node.func.value.id == "monkeypatch" and node.args):
            target = node.args[0]
            while isinstance(target, ast.Attribute):
                target = target.value
            if isinstance(target, ast.Name) and target.id in ours or isinstance(target, ast.Constant) and str(target.value).startswith("dronefleet"):
                found.append(f"line {node.lineno}: {ast.unparse(node)[:80]}")
    # A method replaced on an object by assignment (mypy's method-assign, silenced).
    lines = source.splitlines()
    found += [f"line {tok.start[0]}: {lines[tok.start[0] - 1].strip()[:80]}"
              for tok in tokenize.generate_tokens(io.StringIO(source).readline)
              if tok.type == tokenize.COMMENT and "ignore[method-assign]" in tok.string]
    return found


def test_no_test_patches_our_own_classes() -> None:
    patched = {str(path.relative_to(ROOT)): hits for path in sorted((ROOT / "tests").rglob("*.py"))
               if (hits := our_classes_patched(path.read_text()))}
    assert not patched, patched


def test_the_patch_finder_finds_a_patch_of_our_class() -> None:
    source = "from dronefleet.mission.script import relaying\ndef test(monkeypatch):\n    monkeypatch.setattr(relaying.Relays, 'leash', None)\n"
    assert our_classes_patched(source) == ["line 3: monkeypatch.setattr(relaying.Relays, 'leash', None)"]
    assert our_classes_patched("def test(sim):\n    sim.air.transit = f  # type: ignore[method-assign]\n") == [
        "line 2: sim.air.transit = f  # type: ignore[method-assign]"]
    assert our_classes_patched("import zenoh\ndef test(monkeypatch):\n    monkeypatch.setattr(zenoh, 'scout', None)\n") == []
