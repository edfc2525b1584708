"""``python -m fleet monitor-bench``: throughput and memory of the fleet monitor.

Simulates a pool of distinct 25 s, 1 kHz, 7-signal recordings with the kernel once, then
lays out fleets of N recordings (default 100, 1,000, 10,000) in the MACHINE/AXIS/DATE layout
by hard-linking pool files (the monitor reads and analyses every one of them, so the cost
per recording is real; only the disk space is shared), runs the whole monitor job on each
and reports recordings per minute end to end and the peak memory of the client and of the
workers. A long recording (``--long-s``, default 600 s) against a 25 s one shows that the
memory of one analysis does not grow with the recording's length.
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cmdline.progress import Progress
from plant_sim.physics.simulate import References, simulate
from virtual_bus.atomic import write_atomic
from virtual_bus.formats.axis import dump_axis, load_axis
from virtual_bus.formats.trace import Trace
from virtual_bus.shipped import PAPER_AXIS

from ..analyse import analyse
from ..demo_fleet import TRACE_COLUMNS, simulate_recording
from ..job import monitor
from ..sources import RecordingKind, Source, discover

NAME = "monitor-bench"
HELP = "fleet monitor throughput (recordings/min at 100..10,000 recordings) and memory"


def _counts(text: str) -> list[int]:
    try:
        values = [int(x) for x in text.replace(",", " ").split()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected counts like 100,1000") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: every count must be >= 1")
    return values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--counts",
        type=_counts,
        default=[100, 1000, 10000],
        help="fleet sizes, comma separated (default 100,1000,10000)",
    )
    parser.add_argument("--pool", type=int, default=40, help="distinct simulated recordings")
    parser.add_argument("--workers", type=int, default=2, help="local Dask worker processes")
    parser.add_argument(
        "--long-s",
        type=float,
        default=600.0,
        help="length of the long recording for the memory check, s (0: skip)",
    )
    parser.add_argument("--json", type=Path, help="write the figures as JSON")


def _pool(folder: Path, n: int) -> tuple[list[Path], Path]:
    base = load_axis(PAPER_AXIS)
    rng = np.random.default_rng(7)
    paths = []
    for i in range(n):
        axis = base.with_values({"mechanics.backlash": float(rng.uniform(5e-6, 80e-6))})
        trace = simulate_recording(axis, rng)
        p = folder / f"pool{i:03d}.csv"
        Trace({c: trace[c] for c in TRACE_COLUMNS}).to_csv(p)
        paths.append(p)
    axis_file = folder / "axis.toml"
    write_atomic(axis_file, dump_axis(base))
    return paths, axis_file


def _fleet(folder: Path, pool: list[Path], n: int) -> None:
    start = dt.datetime(2026, 1, 1)
    for i in range(n):
        machine, axis = f"M{i // 300:03d}", "XYZ"[(i // 100) % 3]
        date = start + dt.timedelta(days=i % 100)
        target = folder / machine / axis / f"{date:%Y-%m-%d}T{i:05d}.csv"
        target.parent.mkdir(parents=True, exist_ok=True)
        os.link(pool[i % len(pool)], target)


def _long_recording(folder: Path, seconds: float) -> Path:
    axis = load_axis(PAPER_AXIS)
    cycle = axis.control.position_cycle
    n = round(seconds / cycle)
    t = np.arange(n) * cycle
    speed = 0.05 * np.sign(np.sin(2 * np.pi * t / 20.0))
    position = np.cumsum(speed) * cycle
    trace = simulate(axis, References.from_position(position, cycle))
    path = folder / "long.csv"
    Trace({c: trace[c] for c in TRACE_COLUMNS}).to_csv(path)
    return path


def _peak_rss_mb(analysis: Source) -> float:
    """Peak RSS (MB) of a fresh process that analyses one recording."""
    import subprocess

    code = (
        "import resource, sys; from pathlib import Path\n"
        "from fleet.analyse import analyse\n"
        "from fleet.sources import Source, RecordingKind\n"
        f"r = analyse(Source(Path({str(analysis.path)!r}), RecordingKind.TRACE, 'M', 'X', None,"
        f" Path({str(analysis.axis_file)!r})))\n"
        "assert r.ok, r.error\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    return float(out.stdout.strip())


def run(args: argparse.Namespace) -> int:
    progress = Progress("fleet monitor-bench", quiet=args.quiet)
    work = Path(tempfile.mkdtemp(prefix="monitor-bench-"))
    figures: dict[str, object] = {"workers": args.workers, "cpus": os.cpu_count()}
    try:
        progress.stage(f"simulating a pool of {args.pool} recordings (25 s, 1 kHz, 7 signals)")
        pool_dir = work / "pool"
        pool_dir.mkdir()
        pool, axis_file = _pool(pool_dir, args.pool)
        runs = []
        for n in args.counts:
            fleet = work / f"fleet{n}"
            _fleet(fleet, pool, n)
            found = discover([fleet], axis_file=axis_file)
            progress.stage(f"monitoring {n} recordings on {args.workers} local Dask processes")
            t0 = time.perf_counter()
            result = monitor(found, work / f"out{n}", workers=args.workers)
            elapsed = time.perf_counter() - t0
            assert result.processed == n, f"{result.failed} recordings failed"
            per_min = n / elapsed * 60.0
            runs.append(
                {
                    "recordings": n,
                    "seconds": round(elapsed, 2),
                    "recordings_per_min": round(per_min, 1),
                    "ms_per_recording": round(elapsed / n * 1000.0, 2),
                }
            )
            progress.stage(f"{n} recordings: {elapsed:.1f} s, {per_min:.0f} recordings/min")
            shutil.rmtree(fleet)
        figures["runs"] = runs
        # cost of one more recording between fleet sizes: the fixed cost of starting the
        # Dask cluster and writing tables and figures cancels out
        for before, after in itertools.pairwise(runs):
            extra = after["recordings"] - before["recordings"]
            after["marginal_ms_per_recording"] = round(
                (after["seconds"] - before["seconds"]) / extra * 1000.0, 2
            )
        figures["recordings_per_min"] = {
            str(r["recordings"]): r["recordings_per_min"] for r in runs
        }
        figures["ms_per_recording"] = {str(r["recordings"]): r["ms_per_recording"] for r in runs}
        figures["client_peak_rss_mb"] = round(
            resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1
        )
        figures["workers_peak_rss_mb"] = round(
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1
        )
        if args.long_s > 0:
            progress.stage(f"memory of one analysis: 25 s against {args.long_s:g} s")
            long_path = _long_recording(work, args.long_s)
            figures["analysis_peak_rss_mb"] = {
                "25 s": _peak_rss_mb(
                    Source(pool[0], RecordingKind.TRACE, "M", "X", None, axis_file)
                ),
                f"{args.long_s:g} s": _peak_rss_mb(
                    Source(long_path, RecordingKind.TRACE, "M", "X", None, axis_file)
                ),
                "long_file_mb": round(long_path.stat().st_size / 1e6, 1),
            }
            assert analyse(Source(long_path, RecordingKind.TRACE, "M", "X", None, axis_file)).ok
    finally:
        shutil.rmtree(work, ignore_errors=True)
    text = json.dumps(figures, indent=1)
    print(text)
    if args.json:
        write_atomic(args.json, text + "\n")
    return 0
