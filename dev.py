#!/usr/bin/env python3
"""Create or reuse the project's virtual environment, then run the main job, tests or benchmarks.

    python3 dev.py [--quiet] demo [ARGS]    the main job (see README)
    python3 dev.py [--quiet] test [ARGS]    the whole test suite (pytest ARGS)
    python3 dev.py [--quiet] bench [ARGS]   re-measure the README's figures (--help)
    python3 dev.py [--quiet] python ARGS    any command in the environment

Only the standard library is used here, so this runs on a fresh Python 3.11.
The environment lives in `.venv/`; it is (re)installed when `pyproject.toml` changes, with
pip's own progress shown (`--quiet`: none).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import venv
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".installed-from"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / ("python.exe" if os.name == "nt" else "python")
README = ROOT / "README.md"
BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"


def _say(text: str, quiet: bool) -> None:
    if not quiet:
        print(f"dev.py: {text}", file=sys.stderr, flush=True)


def _ensure_venv(quiet: bool) -> None:
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if PY.exists() and STAMP.exists() and STAMP.read_text().strip() == want:
        return
    t0 = time.monotonic()
    if not PY.exists():
        _say(f"creating the virtual environment {VENV} (with pip, ~10 s)", quiet)
        venv.EnvBuilder(with_pip=True).create(VENV)
    _say(
        "installing the project and its dependencies (numpy, scipy, numba, matplotlib, "
        "python-can, canopen, ...): the first time ~2 min, pip's progress follows",
        quiet,
    )
    pip = [str(PY), "-m", "pip", "install", "--disable-pip-version-check"]
    pip += ["-q"] if quiet else ["--progress-bar", "on" if sys.stderr.isatty() else "off"]
    subprocess.run([*pip, "-e", f"{ROOT}[test]"], check=True, stdout=sys.stderr)
    STAMP.write_text(want + "\n")
    _say(f"environment ready ({time.monotonic() - t0:.0f} s)", quiet)


# --- bench -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Figure:
    """One figure of a benchmark: where it is in the command's JSON (dotted keys; "wall_s" is
    the command's wall time), its unit and the factor from the JSON's SI value to that unit."""

    label: str
    keys: str
    unit: str
    scale: float = 1.0


@dataclass(frozen=True)
class Bench:
    """A command of the project (``python -m ...`` args; ``{out}`` is a fresh directory) and
    the JSON file it writes there (``result``) holding its figures; ``setup``: commands run
    before it, untimed (a setup that fails, e.g. data not present, leaves the figures out);
    ``needs``: a program it runs (not installed: the figures are left out, saying so)."""

    name: str
    args: tuple[str, ...]
    result: str
    figures: tuple[Figure, ...]
    setup: tuple[tuple[str, ...], ...] = ()
    needs: str = ""


def _benches(realtime_s: float) -> tuple[Bench, ...]:
    wall = Figure("wall time of the command", "wall_s", "s")
    rt = f"real time {realtime_s:g} s"
    cmp = "offline_comparison.max_following_error_difference"
    return (
        Bench(
            "paper",
            ("plant_sim", "paper", "--out", "{out}"),
            "summary.json",
            (
                Figure("Fig. 8 limit-cycle frequency", "runs.ordinary.dominant_frequency_hz", "Hz"),
                Figure(
                    "Fig. 8 p2p following error", "runs.ordinary.p2p_following_error", "µm", 1e6
                ),
                Figure(
                    "Fig. 9 p2p following error", "runs.regulated.p2p_following_error", "µm", 1e6
                ),
                Figure("p2p reduction by the regulator", "p2p_reduction", "%", 100.0),
                Figure("Fig. 9 lowest λ", "runs.regulated.min_lambda", "1"),
                wall,
            ),
        ),
        Bench(
            "paper-2.5ms",
            ("plant_sim", "paper", "--out", "{out}", "--position-cycle", "0.0025"),
            "summary.json",
            (
                Figure(
                    "2.5 ms: limit-cycle frequency", "runs.ordinary.dominant_frequency_hz", "Hz"
                ),
                Figure("2.5 ms: p2p reduction", "p2p_reduction", "%", 100.0),
            ),
        ),
        Bench(
            "sweep",
            ("plant_sim", "sweep", "--out", "{out}"),
            "sweep.json",
            (
                Figure("sweep: vibrating cells (of 24)", "verdicts.vibrating_cells", "cells"),
                Figure("sweep: vibrating cells in the band", "verdicts.in_band", "cells"),
                Figure("sweep: f / k_v (least squares)", "verdicts.f_over_kv", "1"),
                Figure("sweep: R² of f = c·k_v", "verdicts.f_over_kv_r2", "1"),
                Figure(
                    "sweep: spread of f over δ",
                    "verdicts.max_relative_spread_over_backlash",
                    "%",
                    100.0,
                ),
                Figure(
                    "sweep: amplitude / (δ/2), lowest",
                    "verdicts.amplitude_over_half_backlash_min",
                    "1",
                ),
                Figure(
                    "sweep: amplitude / (δ/2), highest",
                    "verdicts.amplitude_over_half_backlash_max",
                    "1",
                ),
                wall,
            ),
        ),
        Bench(
            "bridge-demo",
            ("bridge", "demo", "--out", "{out}"),
            "summary.json",
            (
                Figure("over the bus: p2p reduction", "p2p_reduction", "%", 100.0),
                Figure(
                    "bus vs offline, regulated: max following-error difference",
                    f"bridge.runs.regulated.{cmp}",
                    "nm",
                    1e9,
                ),
                Figure(
                    "bus vs offline, ordinary: max following-error difference",
                    f"bridge.runs.ordinary.{cmp}",
                    "µm",
                    1e6,
                ),
                wall,
            ),
        ),
        Bench(
            "emps-diagnose",
            (
                "plant_sim",
                "diagnose",
                "{out}/emps/DATA_EMPS.csv",
                "--axis",
                "config/emps_nominal.toml",
                "--out",
                "{out}/diagnosis",
            ),
            "diagnosis/report.json",
            (
                Figure("EMPS diagnosis: time of the diagnosis", "timings_s.total", "s"),
                Figure("EMPS diagnosis: its evidence stage", "timings_s.evidence", "s"),
                Figure(
                    "EMPS diagnosis: torque fit, fitted model",
                    "fit_after.motor_torque.fit_percent",
                    "%",
                ),
                wall,
            ),
            setup=(("plant_sim", "emps", "--out", "{out}/emps"),),
        ),
        Bench(
            "plant_sim-bench",
            ("plant_sim", "bench", "--all", "--json", "{out}/bench.json"),
            "bench.json",
            (
                Figure("kernel: section X real-time factor", "kernel_realtime_factor", "×"),
                Figure("solve_ivp reference: real-time factor", "reference_realtime_factor", "×"),
                Figure("kernel speed-up over the reference", "speedup_vs_reference", "×"),
                Figure("peak memory (RSS)", "peak_rss_mb", "MB"),
                Figure("section IX identification", "bench_identify.elapsed_s", "s"),
                Figure(
                    "diagnosis of a 12,500-sample recording: evidence stage (worst of 2)",
                    "bench_diagnose.worst_evidence_s",
                    "s",
                ),
                Figure(
                    "diagnosis of a 12,500-sample recording: whole (worst of 2)",
                    "bench_diagnose.worst_wall_s",
                    "s",
                ),
                wall,
            ),
        ),
        Bench(
            "bridge-bench",
            ("bridge", "bench", "--seconds", f"{realtime_s:g}", "--json", "{out}/bench.json"),
            "bench.json",
            (
                Figure("lockstep, full stack", "lockstep.cycles_per_s", "cycles/s"),
                Figure(
                    "lockstep with trace and bus log", "lockstep_recording.cycles_per_s", "cycles/s"
                ),
                Figure(
                    f"{rt}: SYNC-to-set-point latency median", "realtime.latency_us_median", "µs"
                ),
                Figure(f"{rt}: latency p99", "realtime.latency_us_p99", "µs"),
                Figure(f"{rt}: latency max", "realtime.latency_us_max", "µs"),
                Figure(f"{rt}: skipped SYNCs", "realtime.skipped_syncs", "SYNCs"),
                Figure(f"{rt}: cycles without all TPDOs", "realtime.missed_tpdo_cycles", "cycles"),
                wall,
            ),
        ),
        *(_realtime_bench(rate_hz, realtime_s) for rate_hz in (1000, 2000)),
        *(_host_latency_bench(rate_hz, realtime_s) for rate_hz in (1000, 2000)),
        Bench(
            "monitor",
            ("plant_sim", "monitor-bench", "--counts", "100,1000", "--json", "{out}/m.json"),
            "m.json",
            (
                Figure("fleet monitor, 100 recordings", "recordings_per_min.100", "recordings/min"),
                Figure(
                    "fleet monitor, 1,000 recordings", "recordings_per_min.1000", "recordings/min"
                ),
                Figure("one analysis of 25 s: peak RSS", "analysis_peak_rss_mb.25 s", "MB"),
                Figure("one analysis of 600 s: peak RSS", "analysis_peak_rss_mb.600 s", "MB"),
                wall,
            ),
        ),
    )


def _realtime_bench(rate_hz: int, seconds: float) -> Bench:
    """The bridge alone at ``rate_hz`` with every real-time option, busy polling included
    (root: the simulated drive runs as its own process in a private network namespace, with
    the same options on the other CPU)."""
    rt = f"{rate_hz} Hz, SCHED_FIFO, {seconds:g} s"
    return Bench(
        f"bridge-realtime-{rate_hz // 1000}k",
        (
            "bridge",
            "bench",
            "--skip-lockstep",
            "--seconds",
            f"{seconds:g}",
            "--rate-hz",
            str(rate_hz),
            "--rt-priority",
            "50",
            "--cpu",
            "1",
            "--lock-memory",
            "--freeze-gc",
            "--busy-poll",
            "--json",
            "{out}/bench.json",
        ),
        "bench.json",
        (
            Figure(f"{rt}: latency median", "realtime.latency_us_median", "µs"),
            Figure(f"{rt}: latency p99", "realtime.latency_us_p99", "µs"),
            Figure(f"{rt}: latency max", "realtime.latency_us_max", "µs"),
            Figure(f"{rt}: bridge's share p99", "realtime.compute_us_p99", "µs"),
            Figure(f"{rt}: skipped SYNCs", "realtime.skipped_syncs", "SYNCs"),
            Figure(f"{rt}: cycles without all TPDOs", "realtime.missed_tpdo_cycles", "cycles"),
            Figure(f"{rt}: loop CPU per cycle", "realtime.cpu_us_per_cycle", "µs"),
            Figure(f"{rt}: drive CPU per cycle", "realtime.drive_cpu_us_per_cycle", "µs"),
        ),
    )


def _host_latency_bench(rate_hz: int, seconds: float) -> Bench:
    """cyclictest (rt-tests) with the real-time bench's settings: the floor any loop at that
    rate meets on this host (``python -m bridge host-latency``)."""
    host = f"host floor (cyclictest), {rate_hz} Hz, {seconds:g} s"
    return Bench(
        f"host-latency-{rate_hz // 1000}k",
        (
            "bridge",
            "host-latency",
            "--rate-hz",
            str(rate_hz),
            "--seconds",
            f"{seconds:g}",
            "--cpu",
            "1",
            "--rt-priority",
            "50",
            "--json",
            "{out}/host.json",
        ),
        "host.json",
        (
            Figure(f"{host}: wake-up latency p99", "host_latency.latency_us_p99", "µs"),
            Figure(f"{host}: wake-up latency max", "host_latency.latency_us_max", "µs"),
            Figure(f"{host}: wake-ups one cycle late", "host_latency.late_cycles", "cycles"),
            Figure(f"{host}: hypervisor steal, CPU 1", "host_latency.host_steal_ms.cpu1", "ms"),
        ),
        needs="cyclictest",
    )


def _lookup(doc: object, keys: str) -> float | None:
    for key in keys.split("."):
        if not isinstance(doc, dict) or key not in doc:
            return None
        doc = doc[key]
    return float(doc) if isinstance(doc, int | float) and not isinstance(doc, bool) else None


def _run_bench(bench: Bench, quiet: bool) -> dict[str, float | None]:
    if bench.needs and shutil.which(bench.needs) is None:
        _say(f"{bench.needs} is not installed: {bench.name} left out", quiet)
        return {f.label: None for f in bench.figures}
    with tempfile.TemporaryDirectory(prefix="dev-bench-") as tmp:
        for setup in bench.setup:
            cmd = [str(PY), "-m", *(a.replace("{out}", tmp) for a in setup), "--quiet"]
            if subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL).returncode != 0:
                _say(f"`{' '.join(setup)}` failed: {bench.name} left out", quiet)
                return {f.label: None for f in bench.figures}
        args = [a.replace("{out}", tmp) for a in bench.args]
        cmd = [str(PY), "-m", *args, *(["--quiet"] if quiet else [])]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(f"dev.py bench: `{' '.join(args)}` failed (exit {done.returncode})")
        doc = json.loads((Path(tmp) / bench.result).read_text())
    doc["wall_s"] = wall
    return {f.label: _lookup(doc, f.keys) for f in bench.figures}


def _number(value: float) -> str:
    return f"{value:,.0f}" if 1000 <= abs(value) < 1e7 else f"{value:.3g}"


def _table(rows: list[tuple[Bench, Figure, list[float | None]]], runs: int, note: str) -> str:
    lines = [
        f"Measured by `python3 dev.py bench --runs {runs}` ({note}); "
        "min / median / max over the runs.",
        "",
        "| figure | min | median | max | unit | command (`python -m ...`) |",
        "|---|---|---|---|---|---|",
    ]
    for bench, fig, values in rows:
        got = [v * fig.scale for v in values if v is not None]
        cells = (
            [_number(min(got)), _number(statistics.median(got)), _number(max(got))]
            if got
            else ["-", "-", "-"]
        )
        command = " ".join(a.replace("{out}", "DIR") for a in bench.args)
        lines.append(f"| {fig.label} | {' | '.join(cells)} | {fig.unit} | `{command}` |")
    return "\n".join(lines)


def replace_between_markers(text: str, table: str) -> str:
    """``text`` with everything between the bench markers replaced by ``table``."""
    pattern = re.compile(re.escape(BEGIN) + r".*?" + re.escape(END), re.DOTALL)
    if len(pattern.findall(text)) != 1:
        raise SystemExit(f"dev.py bench: README.md needs exactly one {BEGIN} ... {END} block")
    return pattern.sub(lambda _: f"{BEGIN}\n{table}\n{END}", text)


def bench(argv: Sequence[str], quiet: bool, run: Callable[[Bench, bool], dict] = _run_bench) -> int:
    parser = argparse.ArgumentParser(
        prog="python3 dev.py bench",
        description="Re-measure the figures of the README (paper reproduction, sweep, bus demo, "
        "benchmarks): each command several times; the table between the bench markers in "
        "README.md is rewritten with min/median/max and the command beside each figure.",
    )
    parser.add_argument("--runs", type=int, default=3, help="runs of each command (default 3)")
    parser.add_argument(
        "--realtime-seconds",
        type=float,
        default=60.0,
        help="length of bridge bench's real-time run (default 60)",
    )
    parser.add_argument(
        "--only", nargs="+", metavar="NAME", help="only these benchmarks (names: see the table)"
    )
    parser.add_argument(
        "--no-readme", action="store_true", help="print the table, leave README.md alone"
    )
    args = parser.parse_args(argv)
    if args.runs < 1 or not args.realtime_seconds > 0:
        parser.error("--runs must be >= 1 and --realtime-seconds > 0")
    benches = _benches(args.realtime_seconds)
    if args.only:
        unknown = sorted(set(args.only) - {b.name for b in benches})
        if unknown:
            parser.error(f"--only: unknown {unknown}; known: {[b.name for b in benches]}")
        benches = tuple(b for b in benches if b.name in args.only)
    results: dict[str, list[dict[str, float | None]]] = {b.name: [] for b in benches}
    total = len(benches) * args.runs
    step = 0
    t0 = time.monotonic()
    for i in range(args.runs):
        for b in benches:
            step += 1
            _say(
                f"[{time.monotonic() - t0:6.0f} s] {step}/{total}: python -m "
                + " ".join(a.replace("{out}", "DIR") for a in b.args)
                + f" (run {i + 1} of {args.runs})",
                quiet,
            )
            results[b.name].append(run(b, quiet))
    rows = [(b, f, [r[f.label] for r in results[b.name]]) for b in benches for f in b.figures]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    note = f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs, load average {load:.1f} at the end"
    table = _table(rows, args.runs, note)
    print(table)
    if not args.no_readme:
        README.write_text(replace_between_markers(README.read_text(encoding="utf-8"), table))
        _say(f"rewrote the table between the bench markers of {README}", quiet)
    return 0


def main(argv: list[str]) -> int:
    quiet = bool(argv) and argv[0] in ("--quiet", "-q")
    if quiet:
        argv = argv[1:]
    if not argv or argv[0] not in {"demo", "test", "python", "bench"}:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    _ensure_venv(quiet)
    verb, rest = argv[0], argv[1:]
    if verb == "bench":
        return bench(rest, quiet)
    if verb == "demo":
        cmd = [str(PY), "-m", "bridge", "demo", *(rest or ["--out", "out/demo"])]
        if quiet:
            cmd.append("--quiet")
    elif verb == "test":
        cmd = [str(PY), "-m", "pytest", *rest]
    else:
        cmd = [str(PY), *rest]
    return subprocess.run(cmd, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
