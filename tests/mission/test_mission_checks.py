"""A mission's text checked before anything flies (issue 59, mission/script/checks.py):
names defined nowhere with the nearest known one, verbs called with arguments they do
not take, a drone's attributes, and units where literals show them. What only running
shows is the preflight's (tests/mission/test_preflight.py)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from click.testing import CliRunner
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from dronefleet.cli import main
from dronefleet.mission.script import units
from dronefleet.mission.script.checks import check_script, parameter_dims, script_names
from dronefleet.mission.script.dsl import verb_signatures
from dronefleet.mission.script.names import VERBS
from dronefleet.mission.script.plugins import PluginLibrary

ROOT = Path(__file__).resolve().parents[2]
REPRO = ROOT.parent / "shared" / "repro"
MISSIONS = sorted(p for p in (ROOT / "examples").glob("*.py") if p.name != "__init__.py") + sorted(REPRO.glob("*.py"))


def test_a_typo_of_a_verb_is_caught_by_check_with_line_column_and_suggestion(tmp_path: Path) -> None:
    script = tmp_path / "typo.py"
    script.write_text("d = assign()\narm(d)\ntakeof(d, 5*m)\n")
    result = CliRunner().invoke(main, ["mission", "check", str(script)])
    assert result.exit_code == 1, result.output
    assert f"{script}:3:1: name error: name 'takeof' is not defined; did you mean 'takeoff'?" in result.output


@pytest.mark.parametrize(("source", "line", "column", "kind", "fragment"), [
    ("d = assign()\nmove(d, forward=10*s)\n", 2, 17, "unit", "move: forward expects a distance (m), got 10 s"),
    ("d = assign()\nsleep(3*m)\n", 2, 7, "unit", "sleep: duration expects a duration (s)"),
    ("d = assign()\nturn(d, by=2*m/s)\n", 2, 12, "unit", "turn: by expects an angle (deg)"),
    ("x = 10*s + 5*m\n", 1, 5, "unit", "cannot add a duration (s) and a distance (m)"),
    ("d = assign()\nmove(d, forwrad=10*m)\n", 2, 1, "call", "unexpected keyword argument 'forwrad'; did you mean 'forward'?"),
    ("d = assign()\ntakeoff(d, 5*m, 3)\n", 2, 1, "call", "takeoff(): too many positional arguments"),
    ("land()\n", 1, 1, "call", "land(): missing a required argument: 'd'"),
    ("d = assign()\nprint(d.batery)\n", 2, 7, "name", "a drone has no attribute 'batery'; did you mean 'battery'?"),
    ("a, b = assign(any_drone, any_drone)\nprint(b.rel_alt, b.positon)\n", 2, 18, "name", "'positon'"),
    ("def f():\n    return y\n", 2, 12, "name", "name 'y' is not defined"),
])
def test_what_the_text_shows_is_named_where_it_is(source: str, line: int, column: int, kind: str, fragment: str) -> None:
    problems = check_script(source)
    assert [(p.line, p.column, p.kind) for p in problems] == [(line, column, kind)], problems
    assert fragment in problems[0].message


@pytest.mark.parametrize("source", [
    "d = assign()\nmove(d, forward=10*m, speed=3*m/s, yaw=90*deg, up=-2*m)\nsleep(500*ms)\n",
    "d = assign()\ndist = 10\nmove(d, forward=dist * m)\nturn(d, by=-90)\n",  # bare numbers are the base unit
    "def go(d):\n    print(d.anything_at_all)\nrun(go, assign())\n",  # a parameter: only running shows what it is
    "s = 3\nd = assign()\nsleep(s * m)\n",  # a unit the script redefines is not one
    "def takeoff(d, alt):\n    pass\ntakeoff(1, 2, 3)\n",  # nor a verb
    "args = [assign()]\nland(*args)\n",
    "import math\nfor i in range(3):\n    x = math.sqrt(i)\nprint(x, [j for j in range(2)], pi, north)\n",
    "d = assign()\ntry:\n    t = d.sensor.temperature\nexcept AttributeError:\n    t = None\n",
])
def test_valid_scripts_have_no_problems(source: str) -> None:
    assert check_script(source) == []


@pytest.mark.parametrize("path", MISSIONS, ids=lambda p: p.name)
def test_every_example_and_repro_mission_checks_clean(path: Path) -> None:
    assert check_script(path.read_text(), str(path), PluginLibrary.default(None).verbs()) == []


def test_a_plugins_verbs_are_known_where_the_plugin_is_loaded() -> None:
    source = "enable('mapping')\nmap_area(assign(), 10)\n"
    assert [p.message for p in check_script(source)] == ["name 'map_area' is not defined"]
    assert check_script(source, plugin_verbs=PluginLibrary.default(None).verbs()) == []


@settings(max_examples=300, deadline=None)
@given(verb=st.sampled_from(VERBS), at=st.integers(0, 20), letter=st.sampled_from("abcdefghijklmnopqrstuvwxyz_"),
       edit=st.sampled_from(["drop", "swap", "insert"]), indent=st.integers(0, 3))
def test_any_one_letter_typo_of_a_verb_is_named_with_a_known_name(verb: str, at: int, letter: str, edit: str,
                                                                  indent: int) -> None:
    i = at % len(verb)
    typo = {"drop": verb[:i] + verb[i + 1:], "swap": verb[:i] + letter + verb[i + 1:],
            "insert": verb[:i] + letter + verb[i:]}[edit]
    assume(typo.isidentifier() and typo not in script_names() and not typo.startswith("_"))
    assume(typo not in {"True", "False", "None"} and not _keyword(typo))
    source = "d = assign()\nif d:\n" + " " * (indent + 1) + f"{typo}(d)\n"
    problems = check_script(source)
    assert [(p.line, p.column, p.kind) for p in problems] == [(3, indent + 2, "name")], problems
    message = problems[0].message
    assert message.startswith(f"name {typo!r} is not defined")
    if len(verb) >= 4:  # short names have too many neighbours to name one
        suggested = message.split("did you mean ")[1].strip("'?")
        assert suggested in script_names()


@settings(max_examples=300, deadline=None)
@given(data=st.data(), k=st.floats(0.1, 1000, allow_nan=False), unit=st.sampled_from(sorted(units.UNITS)))
def test_a_literal_in_the_wrong_unit_is_caught_and_in_the_right_one_is_not(data: st.DataObject, k: float,
                                                                           unit: str) -> None:
    pairs = [(v, p) for v, params in parameter_dims().items() for p in params]
    verb, param = data.draw(st.sampled_from(pairs))
    required = [n for n, q in verb_signatures()[verb].parameters.items()
                if q.default is q.empty and q.kind is q.POSITIONAL_OR_KEYWORD and n != param]
    call = f"{verb}({''.join(f'{n}=d, ' for n in required)}{param}={k!r}*{unit})"
    problems = check_script(f"d = assign()\n{call}\n")
    right = units.UNITS[unit].dims == parameter_dims()[verb][param]
    assert [p.kind for p in problems] == ([] if right else ["unit"]), (call, problems)


def _keyword(name: str) -> bool:
    try:
        ast.parse(f"{name} = 1")
    except SyntaxError:
        return True
    return False
