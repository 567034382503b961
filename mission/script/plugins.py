"""Mission plugins (thesis §5.3, SPEC §5): scripts that missions `enable`.

A plugin is a sandboxed script ending in a declaration:

    plugin(id="replacement", type=monitoring,
           input={"min_battery": (float, 0.25), "drainage": (float, 0.0002)},
           vars={"count": 0}, callback=main)

`type=monitoring` calls `callback(drone)` after every telemetry update of every drone
of the mission (drones assigned later too) until the drone is revoked, the plugin is
disabled or the mission ends. `type=verbs` exposes functions (`verbs=[map_area]`)
that the mission then calls like built-in verbs.

At ground start every plugin file (the bundled ones, then the plugins directory, so a
user's file overrides a bundled plugin of the same id) is compiled by the mission
sandbox and run once with verbs disabled, and its declaration is checked. A plugin
with any problem is not loaded at all: its error (file, line, column) is logged and
listed by `GET /plugin`.

`enable(id, **inputs)` runs the plugin's script again, on its own namespace, for that
mission: each (mission, plugin) pair has its own globals, inputs and vars, and the
plugin's code calls the mission's verbs on the mission's drones.
"""

from __future__ import annotations

import keyword
import logging
import re
import types
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from dronefleet.mission.lifecycle.greenlets import Stopped
from dronefleet.mission.lifecycle.record import SecurityViolation, script_line
from dronefleet.mission.script import units
from dronefleet.mission.script.drone import call, guarded, handle
from dronefleet.mission.script.host import ScriptHost
from dronefleet.mission.script.names import VERB_NAMES, common_names
from dronefleet.mission.script.sandbox import Guards, ScriptError, compile_mission
from dronefleet.schemas.errors import FleetError

if TYPE_CHECKING:
    from dronefleet.mission.lifecycle.greenlets import Subroutine
    from dronefleet.mission.script.drone import Drone

log = logging.getLogger(__name__)

BUNDLED_DIR = Path(__file__).parents[1] / "bundled"  # mission/bundled
MONITORING = "monitoring"
VERBS = "verbs"
PLUGIN_TYPES = (MONITORING, VERBS)
INPUT_TYPES: dict[type, str] = {float: "float", int: "int", str: "str", bool: "bool", list: "list", dict: "dict"}
ID_PATTERN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
SHADOWABLE = frozenset({"step", "when"})
LOAD_TICKS = 1_000_000  # a plugin's top level that computes longer than this is refused


class PluginError(FleetError):
    """A plugin that cannot be loaded: message and, when known, where."""

    def __init__(self, message: str, line: int | None = None, column: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.line = line
        self.column = column


class InputError(ValueError):
    """`enable()` with inputs the plugin does not accept (mission cause plugin_param)."""


@dataclass(frozen=True)
class Input:
    name: str
    type: type
    default: Any = None
    required: bool = True

    def describe(self) -> InputView:
        default = float(self.default) if isinstance(self.default, units.Quantity) else self.default
        return InputView(name=self.name, type=INPUT_TYPES[self.type], required=self.required,
                         default=None if self.required else default)

    def accept(self, value: Any) -> Any:
        if self.type is float and isinstance(value, units.Quantity):
            return value  # 50*m: a number with its unit, arithmetic keeps working
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        if not isinstance(value, self.type) or (self.type is not bool and isinstance(value, bool)):
            raise InputError(f"input {self.name!r} must be {INPUT_TYPES[self.type]}, got {type(value).__name__} {value!r}")
        return value


@dataclass(frozen=True)
class Plugin:
    id: str
    type: str
    path: str
    code: types.CodeType = field(repr=False)
    inputs: dict[str, Input]
    vars: tuple[str, ...]
    verbs: tuple[str, ...]
    doc: str = ""
    source: str = field(default="", repr=False)  # what was loaded: a mission's own process loads it again

    def describe(self) -> PluginView:
        return PluginView(id=self.id, type=self.type, path=self.path, doc=self.doc,
                          inputs=[i.describe() for i in self.inputs.values()],
                          vars=list(self.vars), verbs=list(self.verbs))

    def check_inputs(self, given: dict[str, Any]) -> dict[str, Any]:
        unknown = sorted(set(given) - set(self.inputs))
        if unknown:
            accepted = ", ".join(self.inputs) or "none"
            raise InputError(f"plugin {self.id!r} has no input {', '.join(map(repr, unknown))} (accepted: {accepted})")
        values = {}
        for spec in self.inputs.values():
            if spec.name in given:
                values[spec.name] = spec.accept(given[spec.name])
            elif spec.required:
                raise InputError(f"plugin {self.id!r} needs input {spec.name!r} ({INPUT_TYPES[spec.type]})")
            else:
                values[spec.name] = spec.default
        return values


class InputView(msgspec.Struct, frozen=True, kw_only=True):
    name: str
    type: str
    required: bool
    default: Any = None


class PluginView(msgspec.Struct, frozen=True, kw_only=True):
    """`GET /plugin`: one loaded plugin."""

    id: str
    type: str
    path: str
    doc: str
    inputs: list[InputView]
    vars: list[str]
    verbs: list[str]


class LoadFailure(msgspec.Struct, frozen=True, kw_only=True):
    """`GET /plugin`: a plugin file that was not loaded, and why."""

    path: str
    error: str
    line: int | None = None
    column: int | None = None


class PluginListing(msgspec.Struct, frozen=True, kw_only=True):
    plugins: list[PluginView]
    errors: list[LoadFailure]


class Declaration:
    """The `plugin(...)` call a plugin script ends with, captured as it runs."""

    def __init__(self) -> None:
        self.calls: list[dict[str, Any]] = []

    def __call__(self, *, id: Any = None, type: Any = None, input: Any = None,  # noqa: A002 - the thesis's names
                 vars: Any = None, callback: Any = None, verbs: Any = None, doc: Any = "") -> None:
        self.calls.append({"id": id, "type": type, "input": input, "vars": vars, "callback": callback, "verbs": verbs, "doc": doc})

    def one(self) -> dict[str, Any]:
        if len(self.calls) != 1:
            raise PluginError(f"a plugin script must call plugin(...) exactly once (it called it {len(self.calls)} times)")
        return self.calls[0]


def declaration_names(declare: Declaration) -> dict[str, Any]:
    return {"plugin": declare, "monitoring": MONITORING, "verbs": VERBS}


def _inputs(spec: Any, reserved: Iterable[str]) -> dict[str, Input]:
    if spec is None:
        return {}
    if not isinstance(spec, dict):
        raise PluginError("input= must be a dict of name: type or name: (type, default)")
    out = {}
    for name, value in spec.items():
        _check_name(name, "input", reserved)
        if isinstance(value, tuple):
            if len(value) != 2:
                raise PluginError(f"input {name!r}: give a type or (type, default)")
            kind, default = value
            required = False
        else:
            kind, default, required = value, None, True
        if kind not in INPUT_TYPES:
            raise PluginError(f"input {name!r}: type must be one of {', '.join(INPUT_TYPES.values())}, got {kind!r}")
        spec_ = Input(name, kind, default, required)
        if not required:
            try:
                spec_ = Input(name, kind, spec_.accept(default), False)
            except InputError as exc:
                raise PluginError(f"default of {exc}") from None
        out[name] = spec_
    return out


def _check_name(name: Any, what: str, reserved: Iterable[str]) -> None:
    if not isinstance(name, str) or not name.isidentifier() or keyword.iskeyword(name) or name.startswith("_"):
        raise PluginError(f"{what} name {name!r} is not a valid name")
    if name in reserved:
        raise PluginError(f"{what} name {name!r} is already a mission verb or name")


def validate(decl: dict[str, Any], namespace: dict[str, Any], path: str, code: types.CodeType, reserved: frozenset[str],
             source: str = "") -> Plugin:
    plugin_id = decl["id"]
    if not isinstance(plugin_id, str) or not ID_PATTERN.match(plugin_id):
        raise PluginError(f"id must be 1-64 letters, digits, '_' or '-', got {plugin_id!r}")
    kind = decl["type"]
    if kind not in PLUGIN_TYPES:
        raise PluginError(f"type must be monitoring or verbs, got {kind!r}")
    # An input may shadow the bundle builders' names (`step`, `when`) in its own plugin:
    # SPEC §5 enables the relay with `step=4*m`. Verbs and the rest stay reserved.
    inputs = _inputs(decl["input"], reserved - SHADOWABLE)
    variables = decl["vars"] or {}
    if not isinstance(variables, dict):
        raise PluginError("vars= must be a dict of name: initial value")
    for name in variables:
        _check_name(name, "var", reserved | set(inputs))
    verbs: tuple[str, ...] = ()
    if kind == MONITORING:
        callback = decl["callback"]
        if not isinstance(callback, types.FunctionType) or callback.__globals__ is not namespace:
            raise PluginError("a monitoring plugin needs callback= one of its own functions, taking the drone")
        if decl["verbs"]:
            raise PluginError("verbs= is for type=verbs plugins")
    else:
        given = decl["verbs"]
        if not isinstance(given, (list, tuple)) or not given:
            raise PluginError("a verbs plugin needs verbs= a list of its own functions")
        for fn in given:
            if not isinstance(fn, types.FunctionType) or fn.__globals__ is not namespace:
                raise PluginError(f"verbs=: {fn!r} is not a function of this plugin")
            _check_name(fn.__name__, "verb", reserved)
        verbs = tuple(fn.__name__ for fn in given)
        if decl["callback"] is not None:
            raise PluginError("callback= is for type=monitoring plugins")
    doc = decl["doc"] if isinstance(decl["doc"], str) else ""
    return Plugin(id=plugin_id, type=kind, path=path, code=code, inputs=inputs,
                  vars=tuple(variables), verbs=verbs, doc=doc.strip(), source=source)


def load_plugin(path: Path, source: str | None = None) -> Plugin:
    """Compile, run once with verbs disabled, check the declaration. Raises PluginError.
    With `source`, the file is not read (the text it held when the ground loaded it)."""
    if source is None:
        try:
            source = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise PluginError(f"cannot read: {exc}") from None
    try:
        code = compile_mission(source, filename=f"<plugin {path.name}>")
    except ScriptError as exc:
        raise PluginError(exc.message, exc.line, exc.column) from None
    ticks = 0

    def tick() -> None:
        nonlocal ticks
        ticks += 1
        if ticks > LOAD_TICKS:
            raise PluginError("the plugin's top level computes too long at load (define functions, then call plugin())")

    def no_verbs(name: str) -> Callable[..., Any]:
        def refuse(*args: Any, **kwargs: Any) -> None:
            raise PluginError(f"{name}() cannot run while the plugin loads: call verbs inside functions")

        return refuse

    guards = Guards(tick, lambda text: log.info("plugin %s: %s", path.name, text), 0)
    namespace = common_names(guards)
    namespace.update({name: no_verbs(name) for name in VERB_NAMES})
    declare = Declaration()
    namespace.update(declaration_names(declare))
    reserved = frozenset(namespace) | {"plugin", "monitoring", "verbs"}
    try:
        exec(code, namespace)  # noqa: S102 - sandboxed by compile_mission and the guards
    except PluginError:
        raise
    except BaseException as exc:  # noqa: BLE001 - any failure of the script is a load error
        raise PluginError(f"{type(exc).__name__}: {exc}", script_line(exc)) from None
    return validate(declare.one(), namespace, str(path), code, reserved, source)


class PluginLibrary:
    """Every loaded plugin by id, and the files that failed to load."""

    def __init__(self, directories: Iterable[Path] = ()) -> None:
        self.plugins: dict[str, Plugin] = {}
        self.failures: list[LoadFailure] = []
        for directory in directories:
            self.load_dir(directory)

    @classmethod
    def default(cls, plugins_dir: Path | None) -> PluginLibrary:
        """The bundled plugins, then the ground's plugins directory."""
        return cls([BUNDLED_DIR] + ([plugins_dir] if plugins_dir is not None else []))

    def load_dir(self, directory: Path) -> None:
        if not directory.is_dir():
            return
        for path in sorted(directory.glob("*.py")):
            try:
                plugin = load_plugin(path)
            except PluginError as exc:
                self.failures.append(LoadFailure(path=str(path), error=exc.message, line=exc.line, column=exc.column))
                where = f":{exc.line}:{exc.column or 0}" if exc.line else ""
                log.error("plugin %s%s not loaded: %s", path, where, exc.message)
                continue
            previous = self.plugins.get(plugin.id)
            if previous is not None:
                log.warning("plugin %r from %s overrides the one from %s", plugin.id, path, previous.path)
            self.plugins[plugin.id] = plugin
            log.info("plugin %r (%s) loaded from %s", plugin.id, plugin.type, path)

    @classmethod
    def from_sources(cls, sources: Iterable[tuple[str, str]]) -> PluginLibrary:
        """The library again from `sources()` (in a mission's own process)."""
        library = cls()
        for path, source in sources:
            plugin = load_plugin(Path(path), source)
            library.plugins[plugin.id] = plugin
        return library

    def sources(self) -> list[tuple[str, str]]:
        return [(p.path, p.source) for p in self.plugins.values()]

    def verbs(self) -> frozenset[str]:
        """Every verb the loaded plugins add to a mission that enables them."""
        return frozenset(v for p in self.plugins.values() for v in p.verbs)

    def get(self, plugin_id: str) -> Plugin | None:
        return self.plugins.get(plugin_id)

    def describe(self) -> PluginListing:
        return PluginListing(plugins=[self.plugins[k].describe() for k in sorted(self.plugins)], errors=list(self.failures))


class Active:
    """One plugin enabled in one mission: its namespace, and its monitors."""

    def __init__(self, plugin: Plugin, namespace: dict[str, Any], callback: Callable[[Any], Any] | None) -> None:
        self.plugin = plugin
        self.namespace = namespace
        self.callback = callback
        self.enabled = True
        self.monitors: dict[int, tuple[Drone, Subroutine]] = {}  # id(wrapper) → its monitor


class MissionPlugins:
    """The plugins of one mission: enable, disable, monitors that follow its drones."""

    def __init__(self, mission: ScriptHost, library: PluginLibrary | None) -> None:
        self.mission = mission
        self.library = library
        self.active: dict[str, Active] = {}

    def enable(self, plugin_id: str, inputs: dict[str, Any], base: dict[str, Any], mission_names: dict[str, Any]) -> None:
        """Start `plugin_id` for this mission: a fresh namespace from `base` (builtins,
        units, the mission's verbs), its inputs and vars; verbs go into `mission_names`."""
        m = self.mission
        plugin = self.library.get(plugin_id) if self.library is not None else None
        if plugin is None:
            loaded = ", ".join(sorted(self.library.plugins)) if self.library and self.library.plugins else "none"
            raise m.fail("plugin_missing", f"plugin {plugin_id!r} is not loaded (loaded: {loaded})")
        if plugin_id in self.active:
            raise m.fail("plugin_param", f"plugin {plugin_id!r} is already enabled; disable it first")
        try:
            values = plugin.check_inputs(inputs)
        except InputError as exc:
            raise m.fail("plugin_param", str(exc)) from None
        declare = Declaration()
        namespace = dict(base)
        namespace.update(declaration_names(declare))
        try:
            exec(plugin.code, namespace)  # noqa: S102 - checked at load, guarded at run time
            decl = declare.one()
        except BaseException as exc:  # noqa: BLE001 - Stopped/SecurityViolation pass through
            if isinstance(exc, (Stopped, SecurityViolation)):
                raise
            raise m.fail("plugin_error", f"plugin {plugin_id!r} failed to start: {type(exc).__name__}: {exc}") from None
        namespace.update(decl["vars"] or {})
        namespace.update(values)
        active = Active(plugin, namespace, decl["callback"])
        self.active[plugin_id] = active
        m.record.plugins = sorted(set(m.record.plugins) | {plugin_id})  # every plugin the mission used
        m.log("info", f"Plugin {plugin_id} enabled" + (f" with {values}" if values else ""))
        m.changed()
        if plugin.type == MONITORING:
            for wrapper in m.wrappers():
                self._monitor(active, wrapper)
        else:
            for name in plugin.verbs:
                mission_names[name] = self._verb(active, namespace[name])

    def disable(self, plugin_id: str, mission_names: dict[str, Any]) -> None:
        m = self.mission
        if self.library is None or self.library.get(plugin_id) is None:
            raise m.fail("plugin_missing", f"plugin {plugin_id!r} is not loaded")
        active = self.active.pop(plugin_id, None)
        if active is None:
            raise m.fail("plugin_disabled", f"plugin {plugin_id!r} is not enabled in this mission")
        active.enabled = False
        for _, sub in active.monitors.values():
            assert m.scheduler is not None
            m.scheduler.stop(sub)
        active.monitors.clear()
        for name in active.plugin.verbs:
            mission_names.pop(name, None)
        m.log("info", f"Plugin {plugin_id} disabled")

    def drone_added(self, wrapper: Drone) -> None:
        for active in self.active.values():
            if active.plugin.type == MONITORING:
                self._monitor(active, wrapper)

    def drone_removed(self, wrapper: Drone) -> None:
        assert self.mission.scheduler is not None
        for active in self.active.values():
            entry = active.monitors.pop(id(wrapper), None)
            if entry is not None:
                self.mission.scheduler.stop(entry[1])

    def _monitor(self, active: Active, wrapper: Drone) -> None:
        m = self.mission
        callback = active.callback
        assert callback is not None and m.scheduler is not None

        def monitor() -> None:
            while True:
                callback(wrapper)
                call(m, m.next_telemetry(handle(wrapper).live()))

        sub = m.scheduler.spawn(monitor, name=f"plugin {active.plugin.id} on {wrapper.id}", daemon=True,
                                plugin=active.plugin.id)
        active.monitors[id(wrapper)] = (wrapper, sub)

    def _verb(self, active: Active, fn: Callable[..., Any]) -> Callable[..., Any]:
        m = self.mission

        def verb(*args: Any, **kwargs: Any) -> Any:
            if not active.enabled:
                raise m.fail("plugin_disabled", f"{fn.__name__}: plugin {active.plugin.id!r} was disabled")
            return fn(*args, **kwargs)

        verb.__name__ = fn.__name__
        return guarded(verb)


def plugin_summary(library: PluginLibrary) -> str:
    """One line for the ground's start-up output (failures name file, line and column)."""
    text = f"fleet ground: plugins {', '.join(sorted(library.plugins)) or 'none'}"
    for f in library.failures:
        where = f":{f.line}:{f.column or 0}" if f.line else ""
        text += f"\nfleet ground: plugin {f.path}{where} NOT loaded: {f.error}"
    return text


def parse_enable(text: str) -> tuple[str, dict[str, Any]]:
    """`"replacement drainage=0.0015 min_battery=0.3"` → (id, inputs); values are YAML scalars."""
    import yaml

    words = text.replace(",", " ").split()
    if not words:
        raise ValueError("--enable needs a plugin id")
    inputs: dict[str, Any] = {}
    for word in words[1:]:
        key, eq, value = word.partition("=")
        if not eq or not key:
            raise ValueError(f"--enable {words[0]}: expected key=value, got {word!r}")
        inputs[key] = yaml.safe_load(value)
    return words[0], inputs
