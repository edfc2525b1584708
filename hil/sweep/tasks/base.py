"""What a sweep task is, and the helpers every task shares.

A task is a module of this package with ``TASK = Task(name, help, run, summarize, options)``:
``run(spec, options) -> row`` on one axis (``spec`` with its ``seed`` set) returning a flat dict
of scalars, ``summarize(rows) -> figures`` turning the whole table into the figures a README
quotes. Tasks judge the axis only from what a user can measure on it (the FMU's outputs and its
data sheet); ``truth_*`` columns are copied for the summary's scoring only (:func:`truth`) and
never read by the procedure under test.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from plant_sim.fmu import FmuSpec, nominal_axis
from plant_sim.fmu.arguments import AxisSource

Row = dict[str, Any]


@dataclass(frozen=True)
class Task:
    name: str
    help: str
    run: Callable[[FmuSpec, Mapping[str, str]], Row]
    summarize: Callable[[Sequence[Row]], dict[str, Any]]
    options: tuple[str, ...] = ()


def truth(source: AxisSource, *names: str) -> Row:
    """The FMU's scoring values ``truth_NAME`` (for the summary; README: scoring only)."""
    assert source.model is not None
    out: Row = {}
    for name in names:
        value = source.model.nominal.get(f"truth_{name}")
        if value is not None:
            out[f"truth_{name}"] = value
    return out


def fmu_source(spec: FmuSpec) -> AxisSource:
    model = spec.load()
    return AxisSource(nominal_axis(model), spec.describe(), spec, model)
