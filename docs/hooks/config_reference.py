"""mkdocs hook: the configuration keys of the agent, the ground and the world file,
drawn from their schemas (issue 54). A page line `<!-- keys module:Class -->` becomes
a table of every key (nested ones dotted): its type and bounds from the msgspec schema
(`msgspec.inspect`), its default, and the comment the source gives it."""

from __future__ import annotations

import importlib
import inspect
import re
from typing import Any

import msgspec
from msgspec import inspect as mi

MARKER = re.compile(r"^<!-- keys ([\w.]+):(\w+) -->$", re.M)
FIELD = re.compile(r"^\s+(\w+)\s*:")


def on_page_markdown(markdown: str, **_: Any) -> str:
    return MARKER.sub(lambda m: table(getattr(importlib.import_module(m[1]), m[2])), markdown)


def table(cls: type) -> str:
    rows = ["| key | type | default | what it is |", "|---|---|---|---|"]
    rows += [f"| `{key}` | {kind} | {default} | {what} |" for key, kind, default, what in keys(cls)]
    return "\n".join(rows)


def keys(cls: type, prefix: str = "") -> list[tuple[str, str, str, str]]:
    info = mi.type_info(cls)
    assert isinstance(info, mi.StructType), cls
    said = comments(cls)
    out: list[tuple[str, str, str, str]] = []
    for f in info.fields:
        key = prefix + f.encode_name
        what = said.get(f.name, "").replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")
        out.append((key, kind_of(f.type), default_of(f), what))
        nested = struct_of(f.type)
        if nested is not None:
            out += keys(nested.cls, key + ("[]." if isinstance(f.type, mi.ListType) else "."))
    return out


def struct_of(t: mi.Type) -> mi.StructType | None:
    if isinstance(t, mi.StructType):
        return t
    if isinstance(t, mi.ListType):
        return struct_of(t.item_type)
    if isinstance(t, mi.UnionType):
        found = [s for s in (struct_of(u) for u in t.types) if s is not None]
        return found[0] if len(found) == 1 else None
    return None


def kind_of(t: mi.Type) -> str:
    if isinstance(t, mi.UnionType):
        parts = [kind_of(u) for u in t.types if not isinstance(u, mi.NoneType)]
        return " or ".join(parts) + (", or none" if any(isinstance(u, mi.NoneType) for u in t.types) else "")
    if isinstance(t, mi.LiteralType):
        return " \\| ".join(f"`{v}`" for v in t.values)
    if isinstance(t, mi.ListType):
        return f"list of {kind_of(t.item_type)}"
    if isinstance(t, mi.TupleType):
        return f"({', '.join(kind_of(u) for u in t.item_types)})"
    if isinstance(t, mi.VarTupleType):
        return f"list of {kind_of(t.item_type)}"
    if isinstance(t, mi.DictType):
        return f"map of {kind_of(t.key_type)} → {kind_of(t.value_type)}"
    if isinstance(t, mi.StructType):
        return t.cls.__name__
    name = {mi.IntType: "int", mi.FloatType: "float", mi.StrType: "text", mi.BoolType: "bool"}.get(type(t), type(t).__name__)
    bounds = [f"{symbol} {getattr(t, attr):g}" for attr, symbol in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"))
              if getattr(t, attr, None) is not None]
    if getattr(t, "min_length", None):
        bounds.append(f"at least {t.min_length} long")  # type: ignore[attr-defined]
    return name + (f" ({', '.join(bounds)})" if bounds else "")


def default_of(f: mi.Field) -> str:
    if f.required:
        return "required"
    value = f.default if f.default is not msgspec.NODEFAULT else f.default_factory()
    if isinstance(value, msgspec.Struct):
        return "(below)"
    return f"`{msgspec.json.encode(value).decode()}`"


def comments(cls: type) -> dict[str, str]:
    """Each field's comment in the class's source: the lines of `#` just above it and
    the one after it on its line."""
    lines, _ = inspect.getsourcelines(cls)
    said: dict[str, str] = {}
    above: list[str] = []
    for line in lines[1:]:
        stripped = line.strip()
        if stripped.startswith("#"):
            above.append(stripped.lstrip("# "))
            continue
        m = FIELD.match(line)
        if m and "def " not in line:
            trailing = line.split("  # ", 1)[1].strip() if "  # " in line else ""
            said[m[1]] = " ".join([*above, trailing]).strip()
        above = []
    return said
