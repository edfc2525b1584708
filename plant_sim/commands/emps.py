"""``python -m plant_sim emps --out DIR [MAT ...]``: EMPS recordings -> servo trace files.

Converts the EMPS .mat files (MATLAB v5; default: the estimation and validation recordings
of ``shared/data/emps``) to ``DIR/<stem>.csv`` (docs/trace-file.md; columns and
timing: docs/emps.md, :mod:`plant_sim.datasets.emps`).
"""

from __future__ import annotations

import argparse

from cmdline import cli

from ..datasets.emps import (
    DATA_DIR,
    ESTIMATION_FILE,
    VALIDATION_FILE,
    control_law_residual_v,
    import_emps,
)

NAME = "emps"
HELP = "convert the EMPS recordings (.mat) to trace files"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cli.add_inputs(
        parser,
        "mat",
        f"EMPS .mat files; default: {ESTIMATION_FILE} and {VALIDATION_FILE} in {DATA_DIR}",
    )
    cli.add_output_dir(parser)


def run(args: argparse.Namespace) -> int:
    sources = args.mat or [DATA_DIR / ESTIMATION_FILE, DATA_DIR / VALIDATION_FILE]
    done = import_emps(sources, args.out)
    for item in done:
        rec = item.recording
        print(
            f"{item.target}: {item.rows} rows, "
            f"{rec.time_s[-1] - rec.time_s[0]:.2f} s, gtau = {rec.gtau_n_per_v:g} N/V, "
            f"kp = {rec.kp_per_s:g} 1/s, kv = {rec.kv_v_s_per_m:g} V s/m, pulses: "
            f"{'yes' if rec.has_pulses else 'no'}, control-law residual "
            f"{control_law_residual_v(rec):.3g} V rms"
        )
    return 0
