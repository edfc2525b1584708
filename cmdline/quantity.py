"""Values with units as an engineer reads them: every printed figure of the project's commands
(the diagnosis report, the demo's summary, the bridge's run, the plots).

A value in SI units (m, s, rad, N, N·m, m/s, ...; the diagnosis's ``key_unit``)
is shown with the decimal prefix that puts its number between 1 and 1000 — 28 µm, 2.1 ms,
40.8 N, 12 mN·m, 35 mm/s — and three significant digits. Values compared with each other
(a data sheet and a fitted value, the ends of a range) share one prefix, chosen by the larger.
Units without a prefix rule (kg, kg·m², N·s/m, rad/s, "") keep their unit, and the number
is written without an exponent between 0.001 and a million.
"""

from __future__ import annotations

import math

#: Units that take a decimal prefix, and the prefixes each may take (largest first).
_SMALL = ((1.0, ""), (1e-3, "m"), (1e-6, "µ"), (1e-9, "n"))
PREFIXES: dict[str, tuple[tuple[float, str], ...]] = {
    "m": _SMALL,
    "s": _SMALL,
    "rad": _SMALL,
    "m/s": _SMALL,
    "m/s²": _SMALL,
    "N": ((1e3, "k"), *_SMALL[:3]),
    "N·m": ((1e3, "k"), *_SMALL[:3]),
}


def number(value: float, digits: int = 3) -> str:
    """``value`` to ``digits`` significant digits, without an exponent where it is readable
    (1.5e-3 -> '0.0015', 8557.4 -> '8,560', 3.2e7 -> '3.2e+07')."""
    if not math.isfinite(value):
        return "∞" if value > 0 else ("−∞" if value < 0 else "n/a")
    if value == 0.0:
        return "0"
    mag = abs(value)
    if not 1e-3 <= mag < 1e6:
        return f"{value:.{digits}g}"
    rounded = float(f"{value:.{digits}g}")
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(rounded))))
    text = f"{rounded:,.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text.replace("-", "−")


def prefix_for(unit: str, magnitude: float) -> tuple[float, str]:
    """(scale, shown unit) for values of size ``magnitude`` in ``unit``."""
    choices = PREFIXES.get(unit)
    if not choices or not math.isfinite(magnitude) or magnitude == 0.0:
        return 1.0, unit
    for scale, prefix in choices:
        if magnitude >= scale * 0.9995:  # 0.9995 mm rounds to 1.00 mm, not 1,000 µm
            return scale, prefix + unit
    scale, prefix = choices[-1]
    return scale, prefix + unit


def quantity(value: float | None, unit: str, digits: int = 3, like: float | None = None) -> str:
    """'40.8 N', '2.1 ms', '28 µm'; ``like``: another value the prefix is shared with
    (the larger of the two chooses it). None -> 'none'."""
    if value is None:
        return "none"
    magnitude = max(abs(value), abs(like) if like is not None and math.isfinite(like) else 0.0)
    scale, shown = prefix_for(unit, magnitude)
    return f"{number(value / scale, digits)} {shown}".rstrip()


def resolved(value: float, unit: str, floor: float = 1e-9, digits: int = 3) -> str:
    """:func:`quantity`, or 'below 1 nm' (``floor`` in ``unit``) for a smaller magnitude: a
    standstill error of 3e-14 m is rounding, not 3e-05 nm."""
    if math.isfinite(value) and abs(value) < floor:
        return f"below {quantity(floor, unit, digits)}"
    return quantity(value, unit, digits)


def quantities(values: list[float], unit: str, digits: int = 3, sep: str = " … ") -> str:
    """Several values with one prefix and the unit once: '0 … 10.5 mm'."""
    finite = [abs(v) for v in values if math.isfinite(v)]
    scale, shown = prefix_for(unit, max(finite, default=0.0))
    return (sep.join(number(v / scale, digits) for v in values) + f" {shown}").rstrip()


def ratio(new: float | None, old: float | None) -> float | None:
    """new / old where both have one sign and old is not zero (a factor an engineer reads)."""
    if new is None or old is None or old == 0.0 or not (math.isfinite(new) and math.isfinite(old)):
        return None
    r = new / old
    return r if r > 0.0 else None


def factor(r: float) -> str:
    """'2.0×', '0.48×', '15×'."""
    return f"{r:.1f}×" if 1.0 <= r < 10.0 else f"{number(r, 2)}×"


def percent(value: float, digits: int = 1) -> str:
    if not math.isfinite(value):
        return "n/a"
    return f"{value:.{digits}f} %".replace("-", "−")
