"""Lengths, speeds and accelerations in the units an engineer reads (µm, mm/s, m/s²).

Load units are metres on a linear axis and radians on a rotary one (docs/axis-file.md); the
printed and plotted values of the commissioning tests use these helpers, never a bare
``5.19e-05``.
"""

from __future__ import annotations

import math

#: Below this a length is printed as 0 (a floating-point rest, not a measurement).
ZERO_BELOW = 1e-10


def _prefixed(value: float, unit: str, digits: int) -> tuple[float, str]:
    base = "rad" if unit == "rad" else "m"
    a = abs(value)
    if a < 1e-3:
        return value * 1e6, f"µ{base}"
    if a < 1.0:
        return value * 1e3, f"m{base}"
    return value, base


def length(value: float, unit: str = "m", digits: int = 3) -> str:
    """``value`` load units as text with a prefix: 5.19e-05 m -> '51.9 µm', 0.0021 -> '2.1 mm'."""
    if not math.isfinite(value):
        return f"{value} {unit}"
    if abs(value) < ZERO_BELOW:
        return f"0 µ{'rad' if unit == 'rad' else 'm'}"
    scaled, name = _prefixed(value, unit, digits)
    return f"{scaled:.{digits}g} {name}"


def speed(value: float, unit: str = "m", digits: int = 3) -> str:
    """Load units/s with a prefix: 0.02 -> '20 mm/s'."""
    if abs(value) < ZERO_BELOW:
        return f"0 m{'rad' if unit == 'rad' else 'm'}/s"
    scaled, name = _prefixed(value, unit, digits)
    return f"{scaled:.{digits}g} {name}/s"


def acceleration(value: float, unit: str = "m", digits: int = 3) -> str:
    """Load units/s² (no prefix: machine tools state m/s²)."""
    return f"{value:.{digits}g} {'rad' if unit == 'rad' else 'm'}/s²"


def fine_scale(unit: str = "m") -> tuple[float, str]:
    """(factor, name) of the fine unit of a plot axis: (1e6, 'µm') or (1e6, 'µrad')."""
    return 1e6, "µrad" if unit == "rad" else "µm"
