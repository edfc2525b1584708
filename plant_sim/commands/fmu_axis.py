"""``python -m plant_sim fmu-axis --fmu FMU [--fmu-param ...] --out AXIS.toml``.

Checks an FMU as an axis (docs/fmu.md: FMPy's validation, co-simulation, this platform's
binary, the mapped variables' causality and units, the parameters, one initialisation),
prints what it maps and its data sheet, and writes the axis file a user would write from
that data sheet (:func:`plant_sim.fmu.nominal_axis_text`): what ``bridge run --axis``,
``hil demo --axis`` and ``diagnose --axis`` take. Bad FMU, parameter or mapping: one line,
exit 2, nothing written.
"""

from __future__ import annotations

import argparse

from cmdline import cli

from ..errors import FmuError
from ..fmu.arguments import add_fmu_arguments, fmu_spec
from ..fmu.nominal import nominal_axis, nominal_axis_text, nominal_values

NAME = "fmu-axis"
HELP = "check an FMU as an axis and write the axis file of its data sheet"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", type=cli.new_file, metavar="AXIS.toml", help="write the axis file here"
    )
    add_fmu_arguments(parser)


def run(args: argparse.Namespace) -> int:
    spec = fmu_spec(args)
    if spec is None:
        raise FmuError("give --fmu FMU")
    model = spec.load()
    axis = nominal_axis(model)
    text = nominal_axis_text(model)
    print(f"FMU {spec.describe()}: FMI 2.0 co-simulation, checked")
    print(f"  signals: {spec.mapping.describe()}")
    ports = [model.set_point, model.disturbance, *model.measured]
    units = ", ".join(f"{p.variable} ×{p.factor:g} ({p.quantity.value})" for p in ports if p)
    print(f"  to SI: {units}")
    values = nominal_values(model)
    print("  data sheet: " + ", ".join(f"{k} = {v:g}" for k, v in values.items()))
    print(
        f"  axis: {axis.kind.value}, k_r = {axis.transmission_ratio:g} rad/{axis.load_unit}, "
        f"k_v = {axis.control.kv:g} 1/s, position cycle {axis.control.position_cycle * 1e3:g} ms"
    )
    if args.out is not None:
        args.out.write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    return 0
