"""Units for mission scripts: `10*m`, `3*m/s`, `90*deg`, `500*ms`, built by arithmetic.

A Quantity is a value in base units (metres, seconds, degrees) with the exponents of
its dimensions. Adding or comparing quantities of different dimensions raises
UnitError at the line that does it; a bare number stands for the base unit of the
other operand (the DSL's rule: bare numbers mean metres, degrees, seconds, m/s).
Verbs read their arguments through `length()`, `speed()`, `angle()`, `duration()`,
which accept a bare number or a Quantity of the right dimension.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, TypeAlias

from dronefleet.schemas.errors import FleetError

# exponents of (length, time, angle)
Dims = tuple[int, int, int]
_NAMES = {(1, 0, 0): "distance (m)", (0, 1, 0): "duration (s)", (0, 0, 1): "angle (deg)", (1, -1, 0): "speed (m/s)", (0, 0, 0): "number"}
Number = int | float
DISTANCE: Dims = (1, 0, 0)
DURATION: Dims = (0, 1, 0)
ANGLE: Dims = (0, 0, 1)
SPEED: Dims = (1, -1, 0)
# What a verb's parameter takes, in its signature: a bare number (the base unit) or a
# Quantity of that dimension. `fleet mission check` reads them (mission/script/checks.py).
Distance: TypeAlias = Annotated[Any, DISTANCE]
Duration: TypeAlias = Annotated[Any, DURATION]
Angle: TypeAlias = Annotated[Any, ANGLE]
Speed: TypeAlias = Annotated[Any, SPEED]


class UnitError(FleetError, TypeError):
    """Arithmetic or a verb argument that mixes incompatible units."""


def _a(dims: Dims) -> str:
    text = _describe(dims)
    return f"{'an' if text[0] in 'aeiou' else 'a'} {text}"


def described(dims: Dims) -> str:
    """`a distance (m)`, `an angle (deg)`: what a value of these dimensions is."""
    return _a(dims)


def _describe(dims: Dims) -> str:
    if dims in _NAMES:
        return _NAMES[dims]
    parts = [f"{sym}^{exp}" if exp != 1 else sym for sym, exp in zip(("m", "s", "deg"), dims, strict=True) if exp]
    return "·".join(parts)


class Quantity:
    __slots__ = ("value", "dims")

    def __init__(self, value: float, dims: Dims) -> None:
        self.value = float(value)
        self.dims = dims

    # ---- arithmetic -------------------------------------------------------------------

    def _same(self, other: Any, op: str) -> float:
        if isinstance(other, Quantity):
            if other.dims != self.dims:
                raise UnitError(f"cannot {op} {_a(self.dims)} and {_a(other.dims)}")
            return other.value
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return float(other)
        raise UnitError(f"cannot {op} {_a(self.dims)} and {type(other).__name__}")

    def __add__(self, other: Any) -> Quantity:
        return Quantity(self.value + self._same(other, "add"), self.dims)

    __radd__ = __add__

    def __sub__(self, other: Any) -> Quantity:
        return Quantity(self.value - self._same(other, "subtract"), self.dims)

    def __rsub__(self, other: Any) -> Quantity:
        return Quantity(self._same(other, "subtract") - self.value, self.dims)

    def __mul__(self, other: Any) -> Quantity | float:
        if isinstance(other, Quantity):
            return _make(self.value * other.value, tuple(a + b for a, b in zip(self.dims, other.dims, strict=True)))  # type: ignore[arg-type]
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return Quantity(self.value * other, self.dims)
        return NotImplemented

    __rmul__ = __mul__

    def __truediv__(self, other: Any) -> Quantity | float:
        if isinstance(other, Quantity):
            return _make(self.value / other.value, tuple(a - b for a, b in zip(self.dims, other.dims, strict=True)))  # type: ignore[arg-type]
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return Quantity(self.value / other, self.dims)
        return NotImplemented

    def __rtruediv__(self, other: Any) -> Quantity:
        if isinstance(other, (int, float)) and not isinstance(other, bool):
            return Quantity(other / self.value, tuple(-d for d in self.dims))  # type: ignore[arg-type]
        return NotImplemented

    def __neg__(self) -> Quantity:
        return Quantity(-self.value, self.dims)

    def __pos__(self) -> Quantity:
        return self

    def __abs__(self) -> Quantity:
        return Quantity(abs(self.value), self.dims)

    # ---- comparison ---------------------------------------------------------------------

    def __eq__(self, other: object) -> bool:
        try:
            return self.value == self._same(other, "compare")
        except UnitError:
            return False

    def __hash__(self) -> int:
        return hash((self.value, self.dims))

    def __lt__(self, other: Any) -> bool:
        return self.value < self._same(other, "compare")

    def __le__(self, other: Any) -> bool:
        return self.value <= self._same(other, "compare")

    def __gt__(self, other: Any) -> bool:
        return self.value > self._same(other, "compare")

    def __ge__(self, other: Any) -> bool:
        return self.value >= self._same(other, "compare")

    def __float__(self) -> float:
        return self.value

    def __repr__(self) -> str:
        unit = {(1, 0, 0): "m", (0, 1, 0): "s", (0, 0, 1): "deg", (1, -1, 0): "m/s"}.get(self.dims)
        return f"{self.value:g} {unit}" if unit else f"{self.value:g} {_describe(self.dims)}"


def _make(value: float, dims: Dims) -> Quantity | float:
    """Dimensionless results (m/m) are plain numbers."""
    return value if dims == (0, 0, 0) else Quantity(value, dims)


m = meters = Quantity(1.0, (1, 0, 0))
cm = Quantity(0.01, (1, 0, 0))
km = Quantity(1000.0, (1, 0, 0))
s = Quantity(1.0, (0, 1, 0))
ms = Quantity(0.001, (0, 1, 0))
deg = Quantity(1.0, (0, 0, 1))
UNITS = {"m": m, "meters": meters, "cm": cm, "km": km, "s": s, "ms": ms, "deg": deg}


def _read(value: Any, dims: Dims, what: str) -> float:
    if isinstance(value, Quantity):
        if value.dims != dims:
            raise UnitError(f"{what}: expected {_a(dims)}, got {value!r}")
        result = value.value
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        result = float(value)
    else:
        raise UnitError(f"{what}: expected {_a(dims)}, got {type(value).__name__} {value!r}")
    if not math.isfinite(result):
        raise UnitError(f"{what}: must be finite, got {result}")
    return result


def length(value: Any, what: str = "distance") -> float:
    """Metres."""
    return _read(value, DISTANCE, what)


def duration(value: Any, what: str = "duration") -> float:
    """Seconds."""
    return _read(value, DURATION, what)


def angle(value: Any, what: str = "angle") -> float:
    """Degrees."""
    return _read(value, ANGLE, what)


def speed(value: Any, what: str = "speed") -> float:
    """Metres per second."""
    return _read(value, SPEED, what)
