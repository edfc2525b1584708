"""``python -m plant_sim bench``: throughput of the kernel against the solve_ivp reference.

Prints simulated seconds per wall second for the section X scenario (both runs: ordinary and
regulated) with the project kernel and, in the same run, with the plain
``scipy.integrate.solve_ivp`` implementation of the same equations (plant_sim/reference.py),
their ratio and the peak memory. With ``--all`` also the diagnosis and identification
benchmarks (plant_sim/diagnose/bench.py, plant_sim/identify.py) where installed.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import resource
import statistics
import time
from pathlib import Path

from ..model import KernelOptions, default_substeps
from ..reference import simulate_reference
from ..report import LIMIT_CYCLE_VISCOUS
from ..scenarios import SectionX, run_section_x
from .common import add_axis_argument, read_axis

NAME = "bench"
HELP = "kernel throughput vs the solve_ivp reference, peak memory (and --all: diagnosis)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_axis_argument(parser)
    parser.add_argument("--repeat", type=int, default=20, help="kernel repetitions (median)")
    parser.add_argument(
        "--reference-seconds",
        type=float,
        default=2.0,
        help="seconds of the scenario simulated with solve_ivp (default 2: the smooth part, "
        "where the reference is fastest; over the limit cycle RK45 resolves every sign(v) "
        "switch and the full 7 s took 745 s here)",
    )
    parser.add_argument("--all", action="store_true", help="also the diagnosis benchmarks")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def run(args: argparse.Namespace) -> int:
    if args.repeat < 1:
        raise SystemExit("python -m plant_sim bench: --repeat must be >= 1")
    axis = read_axis(args.axis).with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
    scenario = SectionX()
    sim_s = scenario.end_s
    run_section_x(axis, True)  # compile / load the cached kernel outside the timing
    walls = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        run_section_x(axis, False)
        run_section_x(axis, True)
        walls.append((time.perf_counter() - t0) / 2)
    kernel_wall = statistics.median(walls)
    kernel_rss = _peak_rss_mb()
    results: dict[str, object] = {
        "machine": f"{platform.machine()}, python {platform.python_version()}",
        "scenario": f"section X, {sim_s:g} s simulated per run, position cycle "
        f"{axis.control.position_cycle * 1e3:g} ms, speed cycle "
        f"{axis.control.speed_cycle * 1e6:g} us, {default_substeps(axis)} substep(s)",
        "kernel_wall_s_per_run": kernel_wall,
        "kernel_realtime_factor": sim_s / kernel_wall,
        # the spread of the repetitions: on a shared machine the median follows the load
        "kernel_realtime_factor_best": sim_s / min(walls),
        "kernel_realtime_factor_worst": sim_s / max(walls),
        "peak_rss_mb_after_kernel": kernel_rss,
    }
    ref_s = min(args.reference_seconds, sim_s)
    refs = scenario.references(axis)
    n = round(ref_s / axis.control.position_cycle)
    from ..simulate import References

    part = References(refs.position[:n], refs.speed[:n], refs.disturbance_nm[:n])
    t0 = time.perf_counter()
    simulate_reference(axis, part)
    ref_wall = time.perf_counter() - t0
    results["reference_wall_s"] = ref_wall
    results["reference_simulated_s"] = ref_s
    results["reference_realtime_factor"] = ref_s / ref_wall
    results["speedup_vs_reference"] = (sim_s / kernel_wall) / (ref_s / ref_wall)
    results["peak_rss_mb"] = _peak_rss_mb()
    results["kernel_options"] = str(KernelOptions())
    if args.all:
        for module, func in (
            ("plant_sim.identify", "bench_identify"),
            ("plant_sim.diagnose.bench", "bench_diagnose"),
        ):
            try:
                bench = getattr(importlib.import_module(module), func)
            except (ModuleNotFoundError, AttributeError):
                results[func] = "not installed"
                continue
            results[func] = bench()
    for key, value in results.items():
        if isinstance(value, dict) and "table" in value:
            print(value["table"])  # a benchmark's own summary (the full dict goes to --json)
        elif isinstance(value, float):
            print(f"{key:32s} {value:.4g}")
        else:
            print(f"{key:32s} {value}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str) + "\n")
    return 0
