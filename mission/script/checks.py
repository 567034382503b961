"""What a mission script's text shows is wrong before anything flies (SPEC §5, issue 59).

`fleet mission check`, `POST /mission/check` (the dashboard's editor), submission and
fast-time simulation refuse a script with:

- the sandbox's problems (sandbox.py): syntax, and what a mission may not do;
- a name defined nowhere — not by the script, not a verb, unit, builtin or a loaded
  plugin's verb — with the nearest known name (pyflakes' scope analysis: a `takeof` is
  caught, a name defined later at module level and used in a function is not);
- a verb called with a keyword it does not take or the wrong number of arguments;
- an attribute a drone does not have (`d.batery`) on a name bound by `assign` or
  `replace` in the same scope;
- units that cannot be right where literals show them: `move(d, forward=10*s)` (a
  duration where a distance goes), `10*s + 5*m`.

What only running shows (a sensor the assigned drone does not carry, a battery that
runs out, a fence crossed) is the preflight's (ground/preflight.py).
"""

from __future__ import annotations

import ast
import difflib
import inspect
import operator
import typing
from collections.abc import Callable, Collection
from functools import cache
from typing import Any

from pyflakes import checker as flakes
from pyflakes import messages as flake_messages

from dronefleet.mission.script import units
from dronefleet.mission.script.drone import Drone
from dronefleet.mission.script.dsl import Verbs, verb_signatures
from dronefleet.mission.script.names import VERB_NAMES, VERBS, common_names
from dronefleet.mission.script.sandbox import Guards, ScriptError, parse_and_check

DRONE_MAKERS = frozenset({"assign", "replace"})  # verbs that hand a script drones
_OPS: dict[type, Callable[[Any, Any], Any]] = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
                                               ast.Div: operator.truediv}


@cache
def script_names() -> frozenset[str]:
    """Every name a mission script gets from its mission: builtins, units, geo, verbs."""
    guards = Guards(lambda: None, lambda line: None, None)
    return frozenset(common_names(guards)) | frozenset(guards.builtins()) | frozenset(VERB_NAMES)


@cache
def drone_attributes() -> frozenset[str]:
    return frozenset(name for name in dir(Drone) if not name.startswith("_"))


@cache
def parameter_dims() -> dict[str, dict[str, units.Dims]]:
    """verb → parameter → the dimension it takes (from the verbs' annotations)."""
    table: dict[str, dict[str, units.Dims]] = {}
    for verb in VERBS:
        hints = typing.get_type_hints(getattr(Verbs, verb), include_extras=True)
        table[verb] = {p: h.__metadata__[0] for p, h in hints.items() if typing.get_origin(h) is typing.Annotated}
    return table


def check_script(source: str, filename: str = "<mission>", plugin_verbs: Collection[str] = ()) -> list[ScriptError]:
    """Every problem the text of a script shows, first one first. `plugin_verbs`: the
    verbs of the plugins loaded where it will run (`enable` adds them to its names)."""
    tree, problems = parse_and_check(source, filename)
    if tree is None:
        return problems
    bound = _bound_names(tree)
    problems += _undefined_names(tree, filename, script_names() | frozenset(plugin_verbs), bound)
    problems += _ScriptReader(bound).read(tree)
    return sorted(problems, key=lambda p: (p.line or 0, p.column or 0))


def first_problem(source: str, filename: str = "<mission>", plugin_verbs: Collection[str] = ()) -> None:
    """Raise the first problem of `check_script`, if any (what a submission does)."""
    problems = check_script(source, filename, plugin_verbs)
    if problems:
        raise problems[0]


def _bound_names(tree: ast.AST) -> frozenset[str]:
    """Every name the script binds anywhere (assigned, defined, imported, a parameter)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Load):
            names.add(node.id)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.alias):
            names.add((node.asname or node.name).split(".")[0])
        elif isinstance(node, ast.ExceptHandler) and node.name:
            names.add(node.name)
    return frozenset(names)


def _suggest(name: str, known: Collection[str]) -> str:
    close = difflib.get_close_matches(name, [k for k in known if not k.startswith("_")], n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _undefined_names(tree: ast.Module, filename: str, known: frozenset[str], bound: frozenset[str]) -> list[ScriptError]:
    found = flakes.Checker(tree, filename=filename, builtins=known)
    problems = []
    for message in found.messages:
        if isinstance(message, (flake_messages.UndefinedName, flake_messages.UndefinedLocal)):
            name = message.message_args[0]
            problems.append(ScriptError(f"name {name!r} is not defined{_suggest(name, known | bound)}",
                                        message.lineno, message.col + 1, "name"))
    return problems


class _ScriptReader(ast.NodeVisitor):
    """Verb calls, drones' attributes and literal units, scope by scope."""

    def __init__(self, bound: frozenset[str]) -> None:
        self.shadowed = bound  # a verb or unit the script redefines is not checked as one
        self.signatures = verb_signatures()
        self.dims = parameter_dims()
        self.problems: list[ScriptError] = []
        self.scopes: list[tuple[set[str], set[str]]] = []  # (its local names, those bound to drones)

    def read(self, tree: ast.Module) -> list[ScriptError]:
        self._scope(tree.body, set())
        return self.problems

    def _problem(self, node: ast.AST, message: str, kind: str) -> None:
        self.problems.append(ScriptError(message, getattr(node, "lineno", None), getattr(node, "col_offset", -1) + 1, kind))

    def _scope(self, body: list[ast.stmt], params: set[str]) -> None:
        local, drones = set(params), set[str]()
        for node in _own_nodes(body):
            if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Load):
                local.add(node.id)
            if isinstance(node, ast.Assign) and _makes_drones(node.value, self.shadowed):
                for target in node.targets:
                    drones.update(e.id for e in ast.walk(target) if isinstance(e, ast.Name))
        self.scopes.append((local, drones - params))
        for stmt in body:
            self.visit(stmt)
        self.scopes.pop()

    def _is_drone(self, name: str) -> bool:
        for local, drones in reversed(self.scopes):
            if name in local or name in drones:
                return name in drones
        return False

    def visit_FunctionDef(self, node: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
        for default in (*node.args.defaults, *[d for d in node.args.kw_defaults if d is not None]):
            self.visit(default)
        for decorator in node.decorator_list:
            self.visit(decorator)
        self._scope(node.body, _parameters(node.args))

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_Lambda(self, node: ast.Lambda) -> None:
        self.scopes.append((_parameters(node.args), set()))
        self.visit(node.body)
        self.scopes.pop()

    def visit_Attribute(self, node: ast.Attribute) -> None:
        if isinstance(node.value, ast.Name) and isinstance(node.ctx, ast.Load) and self._is_drone(node.value.id) \
                and node.attr not in drone_attributes():
            self._problem(node, f"a drone has no attribute {node.attr!r}{_suggest(node.attr, drone_attributes())}",
                          "name")
        self.generic_visit(node)

    def visit_BinOp(self, node: ast.BinOp) -> None:
        try:
            _literal(node, self.shadowed)
        except units.UnitError as exc:
            self._problem(node, str(exc), "unit")
            return  # one problem per expression
        self.generic_visit(node)

    def visit_Call(self, node: ast.Call) -> None:
        self.generic_visit(node)
        verb = node.func.id if isinstance(node.func, ast.Name) else None
        if verb not in self.signatures or verb in self.shadowed:
            return
        if any(isinstance(a, ast.Starred) for a in node.args) or any(k.arg is None for k in node.keywords):
            return  # *args or **kwargs: only running shows what they hold
        signature = self.signatures[verb]
        try:
            bound = signature.bind(*node.args, **{k.arg: k.value for k in node.keywords if k.arg is not None})
        except TypeError as exc:
            self._problem(node, f"{verb}(): {exc}{_keyword_hint(signature, node)}", "call")
            return
        for param, value in bound.arguments.items():
            dims = self.dims[verb].get(param)
            if dims is None or not isinstance(value, ast.expr):
                continue
            try:
                quantity = _literal(value, self.shadowed)
            except units.UnitError:
                continue  # visit_BinOp said it
            if isinstance(quantity, units.Quantity) and quantity.dims != dims:
                self._problem(value, f"{verb}: {param} expects {units.described(dims)}, got {quantity!r}", "unit")


def _keyword_hint(signature: inspect.Signature, node: ast.Call) -> str:
    """The nearest parameter to the first keyword a verb does not take."""
    unknown = [k.arg for k in node.keywords if k.arg is not None and k.arg not in signature.parameters]
    return _suggest(unknown[0], signature.parameters) if unknown else ""


def _parameters(args: ast.arguments) -> set[str]:
    """Every name a function or lambda binds as a parameter (`*rest` and `**options` too)."""
    names = {a.arg for a in (*args.posonlyargs, *args.args, *args.kwonlyargs)}
    return names | {a.arg for a in (args.vararg, args.kwarg) if a is not None}


def _own_nodes(body: list[ast.stmt]) -> list[ast.AST]:
    """The nodes of a scope's statements, not those of functions or lambdas inside."""
    found: list[ast.AST] = []
    stack: list[ast.AST] = list(body)
    while stack:
        node = stack.pop()
        found.append(node)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        stack.extend(ast.iter_child_nodes(node))
    return found


def _makes_drones(value: ast.expr, shadowed: frozenset[str]) -> bool:
    return (isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and value.func.id in DRONE_MAKERS
            and value.func.id not in shadowed)


def _literal(node: ast.AST, shadowed: frozenset[str]) -> Any:
    """The value of an expression of number literals and unit names (`10*m/s`), None for
    any other; UnitError where its units do not go together."""
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return node.value
    if isinstance(node, ast.Name) and node.id in units.UNITS and node.id not in shadowed:
        return units.UNITS[node.id]
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _literal(node.operand, shadowed)
        return None if value is None else (-value if isinstance(node.op, ast.USub) else value)
    if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        left, right = _literal(node.left, shadowed), _literal(node.right, shadowed)
        if left is None or right is None:
            return None
        try:
            return _OPS[type(node.op)](left, right)
        except (ZeroDivisionError, OverflowError):
            return None
    return None
