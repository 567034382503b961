"""House rules the import-linter cannot state (issue 77, ADR 0019): no module reads
another module's underscored members. An underscored attribute read through anything
but `self` or `cls` must be one its own module defines (another instance of its own
class, say); what another module keeps private goes through that module's API."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("agent", "bus", "ground", "mission", "relay", "schemas", "sim", "dronefleet")
# The standard library's public names that begin with an underscore
STDLIB_PUBLIC = {"sys._getframe", "sys._current_frames", "os._exit"}


def _defined(tree: ast.Module) -> set[str]:
    """The underscored names a module defines: functions, classes, class attributes and
    attributes it assigns (`x._name = …`)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return {n for n in names if n.startswith("_")}


def _foreign_reads(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    own = _defined(tree)
    found = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")):
            continue
        if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
            continue
        if node.attr not in own and ast.unparse(node) not in STDLIB_PUBLIC:
            found.append(f"{path.relative_to(REPO)}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_no_module_reads_another_modules_underscored_members() -> None:
    found = [hit for package in PACKAGES for path in sorted((REPO / package).rglob("*.py")) for hit in _foreign_reads(path)]
    assert not found, "underscored members read from another module:\n" + "\n".join(found)
