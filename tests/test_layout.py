"""The house (issue 33, SPEC §1): one top-level import package whose rooms are the
folders at the root of the repository; no import circles among its modules (imports
inside functions count, `if TYPE_CHECKING:` ones do not). Files are split where
concepts separate, not at a line count (issue 56). The layers themselves are import-linter's contracts (pyproject.toml)."""

from __future__ import annotations

import importlib
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
