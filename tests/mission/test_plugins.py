"""Mission plugins (thesis §5.3): loading and validation, every plugin failure cause,
monitors that follow drones assigned later and stop on revoke, namespaces per
(mission, plugin) pair, and `GET /plugin` on a real ground."""

from __future__ import annotations

import subprocess
import textwrap
from pathlib import Path

import httpx
import pytest

from dronefleet.compose import SimField
from dronefleet.mission.lifecycle.record import MissionRecord
from dronefleet.mission.script.plugins import BUNDLED_DIR, PluginLibrary
from dronefleet.sim.radio import RadioModel
from dronefleet.sim.world import World
from tests.harness import GroundProcess, fleet_command

COUNTER = '''
def main(drone):
    global count
    count = count + 1
    print(f"{label} saw {drone.id} ({count})")

plugin(id="counter", type=monitoring, input={"label": (str, "counter")}, vars={"count": 0}, callback=main)
'''
NEEDS_INPUT = '''
def main(drone):
    pass

plugin(id="needs", type=monitoring, input={"level": float}, callback=main)
'''
FAULTY = '''
def main(drone):
    return 1 / 0

plugin(id="faulty", type=monitoring, callback=main)
'''


def library(tmp_path: Path, **plugins: str) -> PluginLibrary:
    directory = tmp_path / "plugins"
    directory.mkdir(exist_ok=True)
    for name, source in plugins.items():
        (directory / f"{name}.py").write_text(textwrap.dedent(source))
    return PluginLibrary.default(directory)


# ---- loading -------------------------------------------------------------------------

BROKEN = {
    "syntax": ("def main(drone)\n    pass\n", "expected ':'", 1),
    "sandbox": ("import os\n", "import of 'os' is not allowed", 1),
    "undeclared": ("def main(drone):\n    pass\n", "exactly once (it called it 0 times)", None),
    "twice": ('def f(d):\n    pass\nplugin(id="a", type=monitoring, callback=f)\nplugin(id="b", type=monitoring, callback=f)\n', "exactly once", None),
    "bad_type": ('def f(d):\n    pass\nplugin(id="t", type="watching", callback=f)\n', "type must be monitoring or verbs", None),
    "bad_id": ('def f(d):\n    pass\nplugin(id="no spaces", type=monitoring, callback=f)\n', "id must be", None),
    "no_callback": ('plugin(id="c", type=monitoring)\n', "needs callback=", None),
    "bad_input_type": ('def f(d):\n    pass\nplugin(id="i", type=monitoring, input={"x": set}, callback=f)\n', "type must be one of", None),
    "bad_default": ('def f(d):\n    pass\nplugin(id="i", type=monitoring, input={"x": (int, "five")}, callback=f)\n', "default of input 'x' must be int", None),
    "shadows_verb": ('def f(d):\n    pass\nplugin(id="v", type=monitoring, vars={"move": 1}, callback=f)\n', "already a mission verb", None),
    "verb_at_load": ('arm(None)\n', "arm() cannot run while the plugin loads", None),
    "fails_at_load": ('x = 1 / 0\n', "ZeroDivisionError", 1),
    "spins_at_load": ('while True:\n    pass\n', "computes too long at load", None),
    "verbs_without_list": ('def f(d):\n    pass\nplugin(id="w", type=verbs)\n', "needs verbs=", None),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_a_broken_plugin_is_listed_with_its_error_and_not_loaded(tmp_path: Path, name: str) -> None:
    source, message, line = BROKEN[name]
    lib = library(tmp_path, good=COUNTER, **{name: source})
    assert sorted(lib.plugins) == ["contour", "counter", "mapping", "relay", "replacement"]  # the rest still load
    (failure,) = lib.failures
    assert failure.path.endswith(f"{name}.py")
    assert message in failure.error
    if line is not None:
        assert failure.line == line


def test_listing_describes_inputs_and_a_user_plugin_overrides_a_bundled_one(tmp_path: Path) -> None:
    override = (BUNDLED_DIR / "replacement.py").read_text().replace('(float, 0.25)', '(float, 0.4)')
    lib = library(tmp_path, counter=COUNTER, replacement=override)
    listing = {p.id: p for p in lib.describe().plugins}
    assert listing["replacement"].path.endswith("plugins/replacement.py")
    inputs = {i.name: i for i in listing["replacement"].inputs}
    assert inputs["min_battery"].default == 0.4 and inputs["drainage"].default == 0.0002
    assert listing["counter"].vars == ["count"] and listing["mapping"].verbs == ["map_area"]
    assert [(i.name, i.type, i.required) for i in listing["counter"].inputs] == [("label", "str", False)]


# ---- in missions (fast time) ---------------------------------------------------------


async def run(lib: PluginLibrary, *scripts: str, n: int = 3, world: World | None = None) -> list[tuple[MissionRecord, list[str]]]:
    """Run the scripts as concurrent missions; each record with its log."""
    field = SimField(world or World(), n, plugins=lib)
    await field.start()
    try:
        assert field.manager is not None
        ids = [field.manager.submit(textwrap.dedent(s)).mission_id for s in scripts]
        records = [await field.run_mission_started(i, max_s=300) for i in ids]
        return [(r, [line.message for line in field.mission_log(r.mission_id)]) for r in records]
    finally:
        await field.close()


CAUSES = {
    "missing": ('enable("nope")\n', "plugin_missing", "'nope' is not loaded"),
    "disable_missing": ('disable("nope")\n', "plugin_missing", "'nope' is not loaded"),
    "disabled": ('disable("counter")\n', "plugin_disabled", "not enabled"),
    "verb_after_disable": (
        'enable("mapping")\nsurvey = map_area\ndisable("mapping")\nsurvey(None, 1, 1, 1, 1)\n',
        "plugin_disabled", "map_area: plugin 'mapping' was disabled",
    ),
    "unknown_input": ('enable("counter", lable="x")\n', "plugin_param", "no input 'lable'"),
    "wrong_type": ('enable("replacement", drainage="lots")\n', "plugin_param", "'drainage' must be float"),
    "missing_input": ('enable("needs")\n', "plugin_param", "needs input 'level'"),
    "twice": ('enable("counter")\nenable("counter")\n', "plugin_param", "already enabled"),
    "callback_fails": ('enable("faulty")\nd = assign()\nsleep(5)\n', "plugin_error", "ZeroDivisionError"),
    "relay_mode": ('enable("relay", mode="chains")\nd = assign()\nsleep(5)\n', "plugin_error",
                   "relay: mode must be one of chain, measured, distance, not 'chains'"),
}


@pytest.mark.parametrize("name", sorted(CAUSES))
async def test_plugin_failure_causes(tmp_path: Path, name: str) -> None:
    script, expected, message = CAUSES[name]
    lib = library(tmp_path, counter=COUNTER, needs=NEEDS_INPUT, faulty=FAULTY)
    [(record, _)] = await run(lib, script)
    assert (record.status, record.cause) == ("failed", expected), record.message
    assert message in (record.message or "")
    if name == "callback_fails":
        assert "faulty.py line 3" in (record.message or "")  # where in the plugin


async def test_a_monitor_follows_drones_assigned_later_and_stops_on_revoke(tmp_path: Path) -> None:
    script = '''
        enable("counter")
        a = assign()
        wait(a)
        wait(a)
        b = assign()
        wait(b)
        wait(b)
        revoke(b)
        print("revoked b")
        wait(a)
        wait(a)
        wait(a)
    '''
    [(record, log)] = await run(library(tmp_path, counter=COUNTER), script)
    assert (record.status, record.cause) == ("finished", "success"), record.message
    assert record.plugins == ["counter"]
    revoked = log.index("revoked b")
    assert any(line.startswith("counter saw drone02") for line in log[:revoked])
    assert not any(line.startswith("counter saw drone02") for line in log[revoked:])
    assert sum(line.startswith("counter saw drone01") for line in log[revoked:]) >= 2


async def test_each_mission_has_its_own_plugin_namespace(tmp_path: Path) -> None:
    first = 'enable("counter", label="first")\nd = assign()\nwait(d)\nwait(d)\nwait(d)\n'
    second = 'enable("counter", label="second")\nd = assign()\nwait(d)\n'
    (r1, log1), (r2, log2) = await run(library(tmp_path, counter=COUNTER), first, second)
    assert r1.status == r2.status == "finished"
    # each mission's count starts at 0 and its label is its own
    assert [line for line in log1 if "saw" in line][0].endswith("(1)") and all(line.startswith("first") for line in log1 if "saw" in line)
    assert [line for line in log2 if "saw" in line][0].endswith("(1)") and all(line.startswith("second") for line in log2 if "saw" in line)


# ---- GET /plugin on a real ground ------------------------------------------------------


@pytest.mark.integration
async def test_ground_lists_plugins_and_load_errors(tmp_path: Path) -> None:
    plugins = tmp_path / "user-plugins"
    plugins.mkdir()
    (plugins / "counter.py").write_text(COUNTER)
    (plugins / "broken.py").write_text("def main(drone)\n    pass\n")
    ground = GroundProcess(tmp_path, plugins_dir=str(plugins))
    try:
        await ground.ready()
        async with httpx.AsyncClient(base_url=ground.url) as http:
            reply = await http.get("/plugin")
        assert reply.status_code == 200
        body = reply.json()
        assert [p["id"] for p in body["plugins"]] == ["contour", "counter", "mapping", "relay", "replacement"]
        counter = next(p for p in body["plugins"] if p["id"] == "counter")
        assert counter["inputs"] == [{"name": "label", "type": "str", "required": False, "default": "counter"}]
        (error,) = body["errors"]
        assert error["path"].endswith("broken.py") and error["line"] == 1 and "expected ':'" in error["error"]
    finally:
        ground.stop()
    assert "broken.py:1" in ground.output() and "NOT loaded" in ground.output()


@pytest.mark.integration
def test_simulate_cli_enables_plugins(tmp_path: Path) -> None:
    script = tmp_path / "m.py"
    script.write_text('d = assign()\nwait(d)\nwait(d)\n')
    plugins = tmp_path / "plugins"
    plugins.mkdir()
    (plugins / "counter.py").write_text(COUNTER)
    def simulate(*extra: str) -> tuple[int, str]:
        done = subprocess.run([*fleet_command("mission", "simulate", str(script), "--plugins-dir", str(plugins)), *extra],
                              capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
        return done.returncode, done.stdout + done.stderr

    code, out = simulate("--enable", "counter label=cli")
    assert code == 0, out
    assert "cli saw drone01 (1)" in out
    code, out = simulate("--enable", "counter", "label=spec-form")  # SPEC §5: --enable PLUGIN key=value…
    assert code == 0, out
    assert "spec-form saw drone01 (1)" in out
    code, out = simulate("stray=1")
    assert code != 0 and "need exactly one --enable" in out
    code, out = simulate("--enable", "nope")
    assert code != 0 and "no plugin 'nope'" in out
    code, out = simulate("--enable", "counter label")
    assert code != 0 and "expected key=value" in out


CLUMSY = '''
def nudge(drone):
    move(drone, forward=5 * m)  # the drone is on the ground, disarmed: refused

def main(drone):
    global count
    if count == 0:
        count = 1
        run(nudge, drone)

plugin(id="clumsy", type=monitoring, vars={"count": 0}, callback=main)
'''


async def test_a_monitoring_plugins_refused_command_is_its_own_problem_not_the_missions(tmp_path: Path) -> None:
    """Issue 32 item 2: a plugin's refused or failed command (a relay's reposition) is
    logged and the plugin goes on; the same command sent by the script itself still
    ends the mission (cmd_exec)."""
    script = '''
        enable("clumsy")
        d = assign()
        for _ in range(4):
            wait(d)
        print("script done")
    '''
    [(record, log)] = await run(library(tmp_path, clumsy=CLUMSY), script)
    assert (record.status, record.cause) == ("finished", "success"), record.message
    refused = [line for line in log if line.startswith("plugin clumsy: goto drone01 refused")]
    assert refused and refused[0].endswith("the plugin goes on"), log
    assert "script done" in log
    [(record, _)] = await run(library(tmp_path), 'd = assign()\nmove(d, forward=5 * m)\n')
    assert (record.status, record.cause) == ("failed", "cmd_exec"), record.message


WANDERER = '''
def scout(drone):
    helper = assign(any_relay)
    arm(helper)
    takeoff(helper, 10 * m)
    move(helper, forward=300 * m, speed=10 * m / s)  # past the radio's 100 m: the ground loses it

def main(drone):
    global started
    if not started:
        started = True
        run(scout, drone)

plugin(id="wanderer", type=monitoring, vars={"started": False}, callback=main)
'''


async def test_a_drone_a_plugin_assigned_out_of_reach_past_the_grace_is_the_plugins_problem(tmp_path: Path) -> None:
    """Issue 32 item 2: a relay (any drone a monitoring plugin assigned) the ground has
    not heard for mission.link_grace_s is logged as the plugin's problem and the mission
    goes on (the plugin plans without it); a drone of the script's own still ends the
    mission `link_lost`."""
    script = '''
        enable("wanderer")
        d = assign("drone01")
        sleep(90 * s)
        print("script done")
    '''
    world = World(radio=RadioModel(good_m=60.0, lost_m=100.0))
    [(record, log)] = await run(library(tmp_path, wanderer=WANDERER), script, world=world)
    assert (record.status, record.cause) == ("finished", "success"), (record.message, log)
    gone = [line for line in log if line.startswith("plugin wanderer: drone0") and "unreachable for 30 s" in line]
    assert gone and gone[0].endswith("the plugin goes on"), log
    assert "script done" in log
    own = 'd = assign("drone01")\narm(d)\ntakeoff(d, 10 * m)\nmove(d, forward=300 * m, speed=10 * m / s)\n'
    [(record, _)] = await run(library(tmp_path), own, world=world)
    assert (record.status, record.cause) == ("failed", "link_lost"), record.message


@pytest.mark.parametrize("mode", ["measured", "chain"])
async def test_the_relay_plugin_runs_with_drones_speaking_every_250_ms(mode: str) -> None:
    """A drone in doubt of the ground publishes its telemetry every 250 ms (ADR 0003).
    The plugin plans once per round of the drones it hears, at most every 0.9 s: the
    rule is relay/rounds.py's, with its properties in tests/relay/test_relay_rounds.py.
    Here the bundled plugin, which asks it on every sample, runs a mission to its end
    with such drones in either mode."""
    field = SimField(World(), 3, telemetry_rate_ms=250)
    await field.start()
    try:
        assert field.manager is not None
        script = f'enable("relay", mode="{mode}")\nd = assign()\narm(d)\ntakeoff(d, 10 * m)\nsleep(20 * s)\n'
        record = await field.run_mission_started(field.manager.submit(script).mission_id, max_s=120)
        assert (record.status, record.cause) == ("finished", "success"), record.message
    finally:
        await field.close()
