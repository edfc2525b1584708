"""``python -m bridge freqresp``: the speed loop's frequency response over the bus (Fig. 2)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cmdline import cli
from regulator.frequency_response import Multisine
from virtual_bus.atomic import replacing

from ..commission.session import CommissioningStopped

if TYPE_CHECKING:
    from ..commission.freqresp import ExcitationPlan, FrequencyResponse

NAME = "freqresp"
HELP = "excite the speed set point (multisine), measure the speed loop and omega_a (Fig. 2)"
DESCRIPTION = (
    "Start the drive like `bridge run`, excite the speed set point with a multisine (random "
    "phases per realization) around an optional slow feed, record 60FFh sent, 606Ch and 6077h "
    "every SYNC, and write the frequency response with its uncertainty, the antiresonance "
    "and the -3 dB bandwidth (freqresp.json, freqresp.csv, bode.png). The path must lie inside "
    "2014h; any stop reason or --torque-limit stops the axis (exit 1); nothing is stored."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .session_args import add_bus_arguments

    add_bus_arguments(parser)
    add_excitation_arguments(parser)


def add_excitation_arguments(parser: argparse.ArgumentParser) -> None:
    """The excitation and its limits (shared with ``python -m hil freqresp``)."""
    parser.add_argument(
        "--torque-limit",
        type=cli.positive_float,
        required=True,
        help="stop the axis above this torque (N m; per mille of the rated torque without 6076h)",
    )
    parser.add_argument(
        "--amplitude", type=cli.positive_float, default=1.0, help="peak set point, rad/s (1)"
    )
    parser.add_argument("--f-min", type=cli.positive_float, default=1.0, help="Hz (1)")
    parser.add_argument("--f-max", type=cli.positive_float, default=450.0, help="Hz (450)")
    parser.add_argument(
        "--corner", type=cli.positive_float, default=20.0, help="1/f amplitudes above, Hz (20)"
    )
    parser.add_argument(
        "--period-samples", type=cli.count, default=1024, help="samples per period (1024)"
    )
    parser.add_argument("--periods", type=cli.count, default=3, help="per realization (3)")
    parser.add_argument("--realizations", type=cli.count, default=8, help="random phases (8)")
    parser.add_argument(
        "--offset-speed",
        type=float,
        default=0.0,
        help="feed during the test, load units/s (0: standstill; no reversal keeps friction "
        "and a closed gap linear)",
    )
    parser.add_argument(
        "--notch-band", type=cli.number_list, help="Hz low,high where omega_a is looked for"
    )


def plan_maker(args: argparse.Namespace) -> Callable[..., ExcitationPlan]:
    """A function cycle_s -> the plan of ``args`` (UsageError for bad combinations)."""
    from ..commission.freqresp import ExcitationPlan

    band = None
    if args.notch_band is not None:
        if len(args.notch_band) != 2 or not 0 < args.notch_band[0] < args.notch_band[1]:
            raise cli.UsageError("--notch-band: two frequencies low,high in Hz, low < high")
        band = (float(args.notch_band[0]), float(args.notch_band[1]))
    if not math.isfinite(args.offset_speed):
        raise cli.UsageError("--offset-speed: a finite number")

    def make_plan(cycle_s: float, sheet_damping: float | None = None) -> ExcitationPlan:
        return ExcitationPlan(
            Multisine(
                cycle_s, args.period_samples, args.f_min, args.f_max, args.amplitude, args.corner
            ),
            periods=args.periods,
            realizations=args.realizations,
            offset_speed=args.offset_speed,
            torque_limit=args.torque_limit,
            notch_band_hz=band,
            sheet_damping=sheet_damping,
        )

    return make_plan


def write_results(
    fr: FrequencyResponse,
    out: Path,
    title: str,
    reference: tuple[str, np.ndarray, np.ndarray] | None = None,
) -> None:
    """freqresp.json, freqresp.csv, bode.png in ``out``; prints the summary."""
    from ..commission.figures import available, bode_figure, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "freqresp.json", fr.summary())
    loop = fr.loop
    columns = [loop.frequency_hz, np.abs(loop.response), loop.phase_deg(), loop.std]
    header = "frequency_hz,magnitude,phase_deg,std"
    if fr.admittance is not None:
        columns += [np.abs(fr.admittance.response), fr.admittance.std]
        header += ",admittance_magnitude,admittance_std"
    with replacing(out / "freqresp.csv") as tmp:
        np.savetxt(tmp, np.column_stack(columns), delimiter=",", header=header)
    files = [out / "freqresp.json", out / "freqresp.csv"]
    if available():
        bode_figure(fr, out / "bode.png", title, reference)
        files.append(out / "bode.png")
    else:
        print(
            "bode.png not drawn: matplotlib is not installed (pip install 'backlash-bridge[sim]')"
        )
    print(fr.describe())
    print("wrote " + ", ".join(str(f) for f in files))


def run(args: argparse.Namespace) -> int:
    from ..commission.freqresp import measure
    from .common import regulated_axis
    from .session_args import started_bridge

    make_plan = plan_maker(args)
    axis = regulated_axis(args.axis)
    make_plan(axis.control.position_cycle)  # bad values: before the bus
    with started_bridge(args) as bridge:
        plan = make_plan(bridge.controller.params.cycle_s, axis.mechanics.damping_ratio)
        try:
            fr = measure(bridge, plan)
        except CommissioningStopped as exc:
            print(f"python -m bridge freqresp: {exc}", file=sys.stderr)
            return 1
    write_results(fr, args.out, f"speed loop of drive {args.drive_id} over the bus")
    return 0
