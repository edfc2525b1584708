"""``python -m hil freqresp``: the speed loop's frequency response on the simulated axis."""

from __future__ import annotations

import argparse

import numpy as np

from bridge.commands.freqresp import add_excitation_arguments, plan_maker, write_results

from .common import add_axis_and_out, simulated_source

NAME = "freqresp"
HELP = "the speed loop's frequency response (Fig. 2) on the simulated axis, offline"
DESCRIPTION = (
    "The excitation and estimate of `python -m bridge freqresp` through the bridge's loop "
    "around the compiled kernel of the axis file (or an FMU's plant, --fmu); the Bode figure "
    "shows the analytic response of the axis file's linearised two-mass model (eq. 2, 6a with "
    "the current lag and the PDO delay) beside the measurement."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_axis_and_out(parser)
    add_excitation_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..offline import analytic_loop, frequency_response

    source = simulated_source(args, args.axis)
    axis = source.axis
    plan = plan_maker(args)(axis.control.position_cycle, axis.mechanics.damping_ratio)
    with source.plant() as plant:
        fr = frequency_response(plant, plan, axis.transmission_ratio, axis.control.kv)
    f = np.geomspace(plan.multisine.f_min_hz, plan.multisine.f_max_hz, 600)
    reference = analytic_loop(axis, f)
    label = "eq. 6a (linearised two-mass, current lag, PDO delay)"
    write_results(
        fr,
        args.out,
        f"speed loop of {source.name}, simulated",
        None if reference is None else (label, f, reference),
    )
    return 0
