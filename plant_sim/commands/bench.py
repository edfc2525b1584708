"""``python -m plant_sim bench``: throughput of the kernel against the solve_ivp reference.

Prints simulated seconds per wall second for the section X scenario (both runs: ordinary and
regulated) with the project kernel and, in the same run, with the plain
``scipy.integrate.solve_ivp`` implementation of the same equations (plant_sim/physics/reference.py),
their ratio and the peak memory. With ``--all`` also the diagnosis and identification
benchmarks (diagnosis/timing.py, plant_sim/identification.py) where installed.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import resource
import statistics
import time
from dataclasses import asdict, is_dataclass

from cmdline import cli
from cmdline.progress import Progress
from virtual_bus.atomic import write_atomic

from ..paper.outputs import LIMIT_CYCLE_VISCOUS
from ..paper.scenarios import SectionX, run_section_x
from ..physics.model import KernelOptions, default_substeps
from ..physics.reference import simulate_reference
from .common import add_axis_argument, regulated_axis

NAME = "bench"
HELP = "kernel throughput vs the solve_ivp reference, peak memory (and --all: diagnosis)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_axis_argument(parser)
    parser.add_argument(
        "--repeat", type=cli.count, default=20, help="kernel repetitions (median; default 20)"
    )
    parser.add_argument(
        "--reference-seconds",
        type=cli.positive_float,
        default=2.0,
        help="seconds of the scenario simulated with solve_ivp (default 2: the smooth part, "
        "where the reference is fastest; over the limit cycle RK45 resolves every sign(v) "
        "switch and the full 7 s took 745 s here)",
    )
    parser.add_argument("--all", action="store_true", help="also the diagnosis benchmarks")
    parser.add_argument("--json", type=cli.new_file, help="also write the figures here (JSON)")
    cli.add_quiet(parser)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _lines(results: dict[str, object], prefix: str = "") -> list[str]:
    """``key value`` per figure; nested results (the diagnosis benchmark) as dotted keys."""
    out = []
    for key, value in results.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and "table" in value:
            out.append(str(value["table"]))  # a benchmark's own summary (all of it in --json)
        elif isinstance(value, dict):
            out += _lines(value, name + ".")
        elif isinstance(value, float):
            out.append(f"{name:40s} {value:.4g}")
        else:
            out.append(f"{name:40s} {value}")
    return out


def run(args: argparse.Namespace) -> int:
    progress = Progress(f"plant_sim {NAME}", quiet=args.quiet)
    axis = regulated_axis(args.axis).with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
    scenario = SectionX()
    sim_s = scenario.end_s
    progress.stage("load the compiled kernel")
    run_section_x(axis, True)  # compile / load the cached kernel outside the timing
    walls = []
    with progress.bar(args.repeat, "kernel: section X, both runs", unit="repeat") as bar:
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            run_section_x(axis, False)
            run_section_x(axis, True)
            walls.append((time.perf_counter() - t0) / 2)
            bar.update()
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
    from ..physics.simulate import References

    part = References(refs.position[:n], refs.speed[:n], refs.disturbance_nm[:n])
    progress.stage(f"solve_ivp reference: {ref_s:g} s of section X")
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
            ("plant_sim.identification", "bench_identify"),
            ("diagnosis.timing", "bench_diagnose"),
        ):
            try:
                bench = getattr(importlib.import_module(module), func)
            except (ModuleNotFoundError, AttributeError):
                results[func] = "not installed"
                continue
            progress.stage(f"{func} ({module})")
            value = bench()
            results[func] = asdict(value) if is_dataclass(value) else value  # type: ignore[arg-type]
    print("\n".join(_lines(results)))
    if args.json:
        write_atomic(args.json, json.dumps(results, indent=2, default=str) + "\n")
    return 0
