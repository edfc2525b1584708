"""The axis file a user would write from an FMU's data sheet.

An FMU of the feed-axis family states its data sheet as calculated parameters
(``nominal_mass``, ``nominal_kv``, ...; :data:`plant_sim.fmu.mapping.NOMINAL_KEYS` maps them to
axis-file keys). :func:`nominal_axis` turns them into an :class:`AxisConfig`: what the bridge
is configured from (k_v, the cycles, k_r, the torque limit) and what the diagnosis starts
from as the nominal model. It says nothing about a hidden effect, as a data sheet does not:
no backlash, no extra friction. The position loop is closed on the load scale, as the
paper's Fig. 1 and the family's README say.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import date
from typing import Any

from virtual_bus.formats.axis import AxisConfig, axis_from_mapping, dump_axis
from virtual_bus.formats.errors import AxisFileError

from ..errors import FmuError
from .model import FmuModel
from .units import Quantity

#: Keys without which no axis file can be written (docs/axis-file.md's required keys).
REQUIRED = (
    "axis.transmission_ratio",
    "mechanics.motor_inertia",
    "mechanics.load_mass",
    "control.kv",
    "control.ksp",
    "control.position_cycle",
    "control.speed_cycle",
)


def nominal_values(model: FmuModel) -> dict[str, float]:
    """Axis-file key -> the FMU's data-sheet value, for every key the FMU states."""
    out: dict[str, float] = {}
    for key, name in model.spec.mapping.nominal.items():
        value = model.nominal.get(name)
        if value is not None:
            out[key] = value
    return out


def nominal_axis(model: FmuModel) -> AxisConfig:
    """The data-sheet axis file of ``model`` (module docstring); raises :class:`FmuError`
    naming the data-sheet values the FMU does not state or states out of range."""
    values = nominal_values(model)
    missing = [k for k in REQUIRED if k not in values]
    if missing:
        names = ", ".join(f"{k} ({model.spec.mapping.nominal.get(k)})" for k in missing)
        raise FmuError(
            f"FMU {model.describe()}: no data-sheet value for {names}; write the axis file by "
            "hand (docs/axis-file.md) and give it with --axis"
        )
    linear = model.measured[1].quantity is Quantity.LENGTH
    doc: dict[str, dict[str, Any]] = {
        "axis": {"kind": "linear" if linear else "rotary"},
        "mechanics": {},
        "friction": {},
        "control": {"position_feedback": "load"},
    }
    for key, value in values.items():
        section, _, name = key.partition(".")
        if name == "load_mass" and not linear:
            name = "load_inertia"
        doc[section][name] = value
    if not values.get("mechanics.antiresonance"):
        doc["mechanics"].pop("antiresonance", None)
        doc["mechanics"].pop("damping_ratio", None)
    _round_cycles(doc["control"])
    try:
        return axis_from_mapping(doc)
    except AxisFileError as exc:
        raise FmuError(
            f"FMU {model.describe()}: its data sheet makes no valid axis file: {exc}"
        ) from None


def _round_cycles(control: dict[str, Any]) -> None:
    """Cycles as the FMU states them to 1 ns, so that 1 ms / 125 µs is a whole multiple."""
    for key in ("position_cycle", "speed_cycle"):
        if key in control:
            control[key] = round(control[key], 9)


def nominal_axis_text(model: FmuModel, extra: Mapping[str, str] | None = None) -> str:
    """:func:`nominal_axis` as an axis file, its header naming where every value came from."""
    axis = nominal_axis(model)
    params = ", ".join(f"{k}={v}" for k, v in model.spec.parameters)
    lines = [
        f"The data-sheet axis of the FMU {model.spec.path.name}"
        + (f" ({params})" if params else ""),
        f"written by `python -m plant_sim fmu-axis` on {date.today().isoformat()} from its",
        "calculated parameters: " + ", ".join(sorted(model.spec.mapping.nominal.values())) + ".",
        "A data sheet says nothing of hidden effects: no backlash, no extra friction here.",
        "position_feedback = load: the position loop on the linear scale (paper Fig. 1).",
    ]
    for key, value in (extra or {}).items():
        lines.append(f"{key}: {value}")
    return dump_axis(axis, header="\n".join(lines))
