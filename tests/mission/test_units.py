"""Mission units: arithmetic builds them, mixing incompatible ones fails at once."""

from __future__ import annotations

import pytest

from dronefleet.mission.script.units import UnitError, angle, cm, deg, duration, km, length, m, ms, s, speed


def test_arithmetic_builds_and_converts_units() -> None:
    assert length(10 * m) == 10.0
    assert length(150 * cm) == pytest.approx(1.5)
    assert length(2 * km + 500 * m) == 2500.0
    assert speed(3 * m / s) == 3.0
    assert speed(36 * km / (3600 * s)) == pytest.approx(10.0)
    assert duration(500 * ms) == 0.5
    assert angle(-90 * deg) == -90.0
    assert (10 * m) / (2 * m) == 5.0  # dimensionless: a plain number
    assert length(m * 3 - 1) == 2.0  # bare numbers are in the base unit
    assert 10 * m > 5 and 3 * m < 4 * m and 1 * km == 1000 * m
    assert repr(5 * m / s) == "5 m/s"


def test_bare_numbers_are_accepted_where_units_are_expected() -> None:
    assert length(7) == 7.0 and speed(2.5) == 2.5 and angle(45) == 45.0 and duration(1) == 1.0


@pytest.mark.parametrize(
    ("expression", "message"),
    [
        (lambda: 10 * m + 5 * s, "cannot add a distance (m) and a duration (s)"),
        (lambda: 10 * m < 5 * deg, "cannot compare a distance (m) and an angle (deg)"),
        (lambda: speed(10 * m), "speed: expected a speed (m/s), got 10 m"),
        (lambda: length(3 * m / s, "forward"), "forward: expected a distance (m), got 3 m/s"),
        (lambda: duration("soon"), "expected a duration (s), got str"),
        (lambda: length(True), "expected a distance (m), got bool"),
        (lambda: length(float("nan") * m), "must be finite"),
    ],
)
def test_mixing_units_is_an_error_naming_both(expression, message: str) -> None:
    with pytest.raises(UnitError, match=message.replace("(", r"\(").replace(")", r"\)")):
        expression()
