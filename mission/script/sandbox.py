"""The mission sandbox: a static check and rewrite at submit, plus guards at run time.

At submit (`compile_mission`) the script is parsed and refused — with line and column —
when it imports outside the allow-list, names anything starting with `_` (dunders,
runtime hooks), touches frame/code/format attributes, names `open`, `exec`, `eval`,
`compile`, `globals` and the like, catches BaseException (bare `except:`), defines a
metaclass or uses async code. The accepted tree is rewritten so that:

- every loop body and function body starts with a call to the runtime's checkpoint
  (`_fleet_tick`): that is how a mission spinning in `while True: pass` is pre-empted
  and cancelled — Python offers no other reliable way on CPython (see
  docs/adr/0001-mission-runtime.md);
- comprehension sources are wrapped so that they tick too;
- `**`, `*` and `<<` go through guards that refuse results too big to compute in one
  uninterruptible C call (`10**10**10`, `"x" * 10**12`).

At run time the script sees only safe builtins: `getattr`/`hasattr` refuse private
names, `__import__` hands out read-only copies of allowed modules with their
submodules and private parts removed, `iter(f, sentinel)`, huge ranges and itertools'
infinite iterators tick, `print` writes to the mission log. A run-time violation
raises `SecurityViolation`, a BaseException the script cannot catch, and the mission
fails with cause `security`.
"""

from __future__ import annotations

import ast
import builtins
import functools
import itertools
import random as _random
import types
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from dronefleet.mission.lifecycle.record import SecurityViolation
from dronefleet.schemas.errors import FleetError

ALLOWED_MODULES = ("math", "random", "statistics", "itertools", "functools", "collections")
HOOK_PREFIX = "_fleet_"

# Attribute names that lead from an ordinary object to frames, code or globals, or
# that format strings with attribute lookups of their own (str.format).
BLOCKED_ATTRS = frozenset({
    "gi_frame", "gi_code", "gi_yieldfrom", "gi_running", "cr_frame", "cr_code", "cr_await",
    "ag_frame", "ag_code", "ag_await", "f_globals", "f_locals", "f_builtins", "f_back",
    "f_code", "f_trace", "f_lasti", "tb_frame", "tb_next", "tb_lasti", "co_code", "co_consts",
    "func_globals", "func_code", "mro", "format", "format_map", "with_traceback",
})
BLOCKED_NAMES = frozenset({
    "open", "exec", "eval", "compile", "globals", "locals", "vars", "dir", "breakpoint",
    "input", "help", "memoryview", "type", "object", "super", "classmethod", "staticmethod",
    "property", "exit", "quit", "setattr", "delattr", "BaseException", "SystemExit",
    "KeyboardInterrupt", "GeneratorExit", "copyright", "credits", "license", "id",
})
SAFE_BUILTINS = (
    "abs", "all", "any", "ascii", "bin", "bool", "bytes", "callable", "chr", "complex",
    "dict", "divmod", "enumerate", "filter", "float", "format", "frozenset", "hash", "hex",
    "int", "isinstance", "issubclass", "len", "list", "map", "max", "min", "next", "oct",
    "ord", "pow", "repr", "reversed", "round", "set", "slice", "sorted", "str", "sum",
    "tuple", "zip", "ArithmeticError", "AssertionError", "AttributeError", "Exception",
    "IndexError", "KeyError", "LookupError", "NameError", "NotImplementedError",
    "OverflowError", "RuntimeError", "StopIteration", "TypeError", "ValueError",
    "ZeroDivisionError", "True", "False", "None",
)
MAX_SEQUENCE = 10_000_000  # items a single `*` may build
MAX_INT_BITS = 1_000_000  # bits a single `**` or `<<` may build
BIG_RANGE = 1_000_000  # ranges longer than this tick while iterated


class ScriptError(FleetError):
    """A script that does not compile or breaks the sandbox where it can be seen."""

    def __init__(self, message: str, line: int | None, column: int | None, kind: str = "script") -> None:
        where = f"line {line}, column {column}: " if line is not None else ""
        super().__init__(f"{where}{message}")
        self.message = message
        self.line = line
        self.column = column
        self.kind = kind  # "syntax" or "security"

    def detail(self) -> dict[str, Any]:
        return {"kind": self.kind, "line": self.line, "column": self.column, "message": self.message}


# ---- static check --------------------------------------------------------------------


class _Checker(ast.NodeVisitor):
    def __init__(self) -> None:
        self.problems: list[ScriptError] = []

    def refuse(self, node: ast.AST, message: str) -> None:
        self.problems.append(ScriptError(
            message, getattr(node, "lineno", None), getattr(node, "col_offset", -1) + 1, "security"
        ))

    def name(self, node: ast.AST, name: str | None, what: str) -> None:
        if name is None:
            return
        if name.startswith("_") and name != "_":
            self.refuse(node, f"{what} {name!r}: names starting with '_' are not allowed in missions")
        elif name in BLOCKED_NAMES:
            self.refuse(node, f"{name!r} is not available in missions")

    def visit_Name(self, node: ast.Name) -> None:
        self.name(node, node.id, "name")

    def visit_Attribute(self, node: ast.Attribute) -> None:
        if node.attr.startswith("_"):
            self.refuse(node, f"attribute {node.attr!r}: private and dunder attributes are not allowed")
        elif node.attr in BLOCKED_ATTRS:
            hint = " (use an f-string)" if node.attr in ("format", "format_map") else ""
            self.refuse(node, f"attribute {node.attr!r} is not available in missions{hint}")
        self.generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self._module(node, alias.name)
            self.name(node, alias.asname, "name")

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level:
            self.refuse(node, "relative imports are not allowed")
            return
        self._module(node, node.module or "")
        for alias in node.names:
            if alias.name == "*":
                self.refuse(node, "`import *` is not allowed")
            self.name(node, alias.name, "name")
            self.name(node, alias.asname, "name")

    def _module(self, node: ast.AST, module: str) -> None:
        if module not in ALLOWED_MODULES:
            self.refuse(node, f"import of {module!r} is not allowed (allowed: {', '.join(ALLOWED_MODULES)})")

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        self.name(node, node.name, "function")
        self.generic_visit(node)

    def visit_AsyncFunctionDef(self, node: ast.AsyncFunctionDef) -> None:
        self.refuse(node, "async functions are not allowed: mission verbs already block")

    def visit_Await(self, node: ast.Await) -> None:
        self.refuse(node, "await is not allowed: mission verbs already block")

    def visit_ClassDef(self, node: ast.ClassDef) -> None:
        self.name(node, node.name, "class")
        if node.keywords:
            self.refuse(node, "class keywords (metaclass=…) are not allowed")
        self.generic_visit(node)

    def visit_arg(self, node: ast.arg) -> None:
        self.name(node, node.arg, "argument")

    def visit_keyword(self, node: ast.keyword) -> None:
        # a keyword argument is a label, not a lookup: `plugin(id=…, type=…)` is fine
        if node.arg is not None and node.arg.startswith("_"):
            self.name(node, node.arg, "keyword")
        self.generic_visit(node)

    def visit_ExceptHandler(self, node: ast.ExceptHandler) -> None:
        if node.type is None:
            self.refuse(node, "a bare `except:` is not allowed; catch Exception (or something narrower)")
        self.name(node, node.name, "name")
        self.generic_visit(node)

    def visit_Global(self, node: ast.Global) -> None:
        for n in node.names:
            self.name(node, n, "name")

    def visit_Nonlocal(self, node: ast.Nonlocal) -> None:
        for n in node.names:
            self.name(node, n, "name")

    def visit_MatchAs(self, node: ast.MatchAs) -> None:
        self.name(node, node.name, "name")
        self.generic_visit(node)

    def visit_MatchStar(self, node: ast.MatchStar) -> None:
        self.name(node, node.name, "name")

    def visit_MatchMapping(self, node: ast.MatchMapping) -> None:
        self.name(node, node.rest, "name")
        self.generic_visit(node)

    def visit_MatchClass(self, node: ast.MatchClass) -> None:
        for attr in node.kwd_attrs:
            if attr.startswith("_") or attr in BLOCKED_ATTRS:
                self.refuse(node, f"attribute {attr!r} is not available in missions")
        self.generic_visit(node)


# ---- rewrite -------------------------------------------------------------------------


def _hook(name: str, node: ast.AST, *args: ast.expr) -> ast.Call:
    call = ast.Call(func=ast.Name(id=HOOK_PREFIX + name, ctx=ast.Load()), args=list(args), keywords=[])
    return ast.copy_location(call, node)


_GUARDED_OPS: dict[type, str] = {ast.Pow: "pow", ast.Mult: "mul", ast.LShift: "lshift"}


class _Rewriter(ast.NodeTransformer):
    def _tick_first(self, node: ast.AST, body: list[ast.stmt]) -> list[ast.stmt]:
        tick = ast.copy_location(ast.Expr(value=_hook("tick", node)), node)
        return [tick, *body]

    def visit_FunctionDef(self, node: ast.FunctionDef) -> ast.AST:
        self.generic_visit(node)
        node.body = self._tick_first(node, node.body)
        return node

    def visit_For(self, node: ast.For) -> ast.AST:
        self.generic_visit(node)
        node.body = self._tick_first(node, node.body)
        return node

    def visit_While(self, node: ast.While) -> ast.AST:
        self.generic_visit(node)
        node.body = self._tick_first(node, node.body)
        return node

    def visit_comprehension(self, node: ast.comprehension) -> ast.AST:
        self.generic_visit(node)
        node.iter = _hook("iter", node.iter, node.iter)
        return node

    def visit_BinOp(self, node: ast.BinOp) -> ast.AST:
        self.generic_visit(node)
        name = _GUARDED_OPS.get(type(node.op))
        return _hook(name, node, node.left, node.right) if name else node

    def visit_AugAssign(self, node: ast.AugAssign) -> ast.AST:
        self.generic_visit(node)
        name = _GUARDED_OPS.get(type(node.op))
        if name is None or not isinstance(node.target, ast.Name):
            return node
        load = ast.copy_location(ast.Name(id=node.target.id, ctx=ast.Load()), node.target)
        value = _hook(name, node, load, node.value)
        return ast.copy_location(ast.Assign(targets=[node.target], value=value), node)


def parse_and_check(source: str, filename: str) -> tuple[ast.Module | None, list[ScriptError]]:
    """The parsed script (None if it does not parse) and its static problems, first first."""
    try:
        tree = ast.parse(source, filename=filename)
    except SyntaxError as exc:
        return None, [ScriptError(exc.msg, exc.lineno, exc.offset, "syntax")]
    except ValueError as exc:  # e.g. NUL bytes in the source
        return None, [ScriptError(str(exc), None, None, "syntax")]
    try:  # what only the compiler sees: `return`, `break` or `yield` out of place
        compile(tree, filename, "exec", dont_inherit=True)
    except SyntaxError as exc:
        return None, [ScriptError(exc.msg, exc.lineno, exc.offset, "syntax")]
    checker = _Checker()
    checker.visit(tree)
    return tree, sorted(checker.problems, key=lambda p: (p.line or 0, p.column or 0))


def check_mission(source: str, filename: str = "<mission>") -> list[ScriptError]:
    """Every static problem of a script (`fleet mission check`), first one first."""
    return parse_and_check(source, filename)[1]


def compile_mission(source: str, filename: str = "<mission>") -> types.CodeType:
    """Check and rewrite a mission script; raise ScriptError for the first problem."""
    tree, problems = parse_and_check(source, filename)
    if problems:
        raise problems[0]
    assert tree is not None
    tree = ast.fix_missing_locations(_Rewriter().visit(tree))
    return compile(tree, filename, "exec", dont_inherit=True)


# ---- run-time guards -----------------------------------------------------------------


def _refuse_name(name: object) -> None:
    if not isinstance(name, str):
        raise TypeError("attribute name must be a string")
    if name.startswith("_") or name in BLOCKED_ATTRS:
        raise SecurityViolation(f"access to attribute {name!r} is not allowed")


def _safe_getattr(obj: object, name: str, *default: object) -> object:
    _refuse_name(name)
    return getattr(obj, name, *default)


def _safe_hasattr(obj: object, name: str) -> bool:
    _refuse_name(name)
    return hasattr(obj, name)


class _ModuleCopy(types.SimpleNamespace):
    """The public, non-module attributes of an allowed module. Reaching for a hidden
    one (`statistics.sys`) is a violation, not a typo."""

    def __getattr__(self, name: str) -> Any:
        hidden: frozenset[str] = vars(self).get("_hidden", frozenset())
        if name in hidden:
            raise SecurityViolation(f"{name!r} of this module is not available in missions")
        raise AttributeError(name)


def _module_copy(module: types.ModuleType, overrides: dict[str, object]) -> _ModuleCopy:
    names = {
        k: v for k, v in vars(module).items()
        if not k.startswith("_") and not isinstance(v, types.ModuleType)
    }
    names.update(overrides)
    copy = _ModuleCopy(**names)
    vars(copy)["_hidden"] = frozenset(vars(module)) - set(names)
    return copy


class Guards:
    """The hooks and builtins one mission's code runs with."""

    def __init__(self, tick: Callable[[], None], print_line: Callable[[str], None], seed: int | None) -> None:
        self.tick = tick
        self.rng = _random.Random(seed)
        self._print_line = print_line
        self._modules: dict[str, _ModuleCopy] = {}

    def _ticking(self, source: Iterable[Any]) -> Iterator[Any]:
        for item in source:
            self.tick()
            yield item

    def iter_hook(self, source: Any) -> Any:
        # Cheap containers are iterated as they are; anything else ticks per item.
        if isinstance(source, (list, tuple, dict, set, frozenset, str, bytes)) and len(source) <= BIG_RANGE:
            return source
        if isinstance(source, range) and len(source) <= BIG_RANGE:
            return source
        return self._ticking(source)

    def _range(self, *args: int) -> Any:
        r = range(*args)
        return r if len(r) <= BIG_RANGE else self._ticking(r)

    def _iter(self, source: Any, *sentinel: Any) -> Any:
        if sentinel:
            return self._ticking(iter(source, *sentinel))
        return iter(source)

    def _print(self, *args: object, sep: str = " ", end: str = "") -> None:
        self._print_line(sep.join(str(a) for a in args) + end)

    def _import(self, name: str, globals_: Any = None, locals_: Any = None, fromlist: Any = (), level: int = 0) -> Any:
        if level or name not in ALLOWED_MODULES:
            raise SecurityViolation(f"import of {name!r} is not allowed")
        if name not in self._modules:
            module = __import__(name)
            overrides: dict[str, object] = {}
            if name == "random":  # one seeded generator per mission: simulations replay
                overrides = {
                    k: getattr(self.rng, k) for k, v in vars(_random).items()
                    # random() and getrandbits() are C methods (BuiltinMethodType): missed
                    # once, they drew from the process's unseeded generator
                    if not k.startswith("_") and isinstance(v, (types.MethodType, types.BuiltinMethodType))
                }
            elif name == "itertools":  # infinite iterators tick, so C consumers stop too
                overrides = {
                    k: self._wrap_infinite(getattr(itertools, k)) for k in ("count", "cycle", "repeat")
                }
            self._modules[name] = _module_copy(module, overrides)
        return self._modules[name]

    def _wrap_infinite(self, factory: Callable[..., Iterator[Any]]) -> Callable[..., Iterator[Any]]:
        @functools.wraps(factory)
        def make(*args: Any, **kwargs: Any) -> Iterator[Any]:
            return self._ticking(factory(*args, **kwargs))

        return make

    def builtins(self) -> dict[str, object]:
        table: dict[str, object] = {name: getattr(builtins, name) for name in SAFE_BUILTINS}
        table.update(
            getattr=_safe_getattr, hasattr=_safe_hasattr, iter=self._iter, range=self._range,
            print=self._print, __import__=self._import, __build_class__=builtins.__build_class__,
            __name__="mission",
        )
        return table

    def hooks(self) -> dict[str, object]:
        return {
            HOOK_PREFIX + "tick": self.tick,
            HOOK_PREFIX + "iter": self.iter_hook,
            HOOK_PREFIX + "pow": _guarded_pow,
            HOOK_PREFIX + "mul": _guarded_mul,
            HOOK_PREFIX + "lshift": _guarded_lshift,
        }


def _guarded_pow(a: Any, b: Any) -> Any:
    if isinstance(a, int) and isinstance(b, int) and b > 0 and abs(a) > 1:
        if b * max(a.bit_length(), 1) > MAX_INT_BITS:
            raise SecurityViolation(f"{a} ** {b} is too large to compute in a mission")
    return a**b


def _guarded_mul(a: Any, b: Any) -> Any:
    for seq, n in ((a, b), (b, a)):
        if isinstance(seq, (str, bytes, list, tuple)) and isinstance(n, int) and len(seq) * n > MAX_SEQUENCE:
            raise SecurityViolation(f"a sequence of {len(seq) * n} items is too large for a mission")
    return a * b


def _guarded_lshift(a: Any, b: Any) -> Any:
    if isinstance(a, int) and isinstance(b, int) and b > MAX_INT_BITS:
        raise SecurityViolation(f"{a} << {b} is too large to compute in a mission")
    return a << b
