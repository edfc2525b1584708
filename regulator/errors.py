"""Exceptions of :mod:`regulator`: one root, each subclass also the matching builtin."""

from __future__ import annotations

import math
import numbers


class RegulatorError(Exception):
    """Root of every error raised by :mod:`regulator`."""


class RegulatorConfigError(RegulatorError, ValueError):
    """A configuration value is outside its allowed range.

    ``field`` names the parameter, ``value`` is what was given.
    """

    def __init__(self, message: str, *, field: str | None = None, value: object = None) -> None:
        super().__init__(message)
        self.field = field
        self.value = value


class RegulatorInputError(RegulatorError, ValueError):
    """A per-cycle input (speed, position) is not a finite number; nothing was changed.

    ``argument`` names the input, ``value`` is what was given.
    """

    def __init__(self, message: str, *, argument: str | None = None, value: object = None) -> None:
        super().__init__(message)
        self.argument = argument
        self.value = value


class AnalysisError(RegulatorError, ValueError):
    """Arguments of an analysis function (signal, frequencies, parameters) are unusable."""


class TuningError(RegulatorError, ValueError):
    """A beta_T tuning run cannot start or cannot find beta_T (:mod:`regulator.tuning`);
    nothing is stored."""


class TuningInputError(TuningError):
    """The tuning's input is unusable (a motion outside the travel, a torque limit below
    friction): refused before anything moves."""


# --- Checks shared by the configuration classes and the per-cycle inputs --------------------


def is_real(value: object) -> bool:
    """True for a real number (int, float, numpy scalar), False for bool and everything else."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def require_positive(field: str, value: object, unit: str) -> float:
    """Return ``value`` as a float if it is a finite real number > 0, else raise.

    The message names the field, the value and the allowed range (``unit`` e.g. ``"s"``).
    """
    if not (is_real(value) and math.isfinite(value) and value > 0):  # type: ignore[arg-type]
        raise RegulatorConfigError(
            f"{field} = {value!r}: must be a finite number > 0 {unit}".rstrip(),
            field=field,
            value=value,
        )
    return float(value)  # type: ignore[arg-type]


def require_int_at_least(field: str, value: object, low: int) -> int:
    """Return ``value`` if it is an int (not bool) >= ``low``, else raise naming the range."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < low:
        raise RegulatorConfigError(
            f"{field} = {value!r}: must be an integer >= {low}", field=field, value=value
        )
    return int(value)


def require_finite_input(argument: str, value: object) -> float:
    """Return a per-cycle input as a float, or raise :class:`RegulatorInputError`."""
    if type(value) is float and math.isfinite(value):  # the per-cycle case: no ABC check
        return value
    if not (is_real(value) and math.isfinite(value)):  # type: ignore[arg-type]
        raise RegulatorInputError(
            f"{argument} = {value!r}: must be a finite real number", argument=argument, value=value
        )
    return float(value)  # type: ignore[arg-type]
