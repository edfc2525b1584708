"""``python3 dev.py bench``: every benchmark of the registry (``tools/benches.toml``, read by
:mod:`tools.benches`) run several times in the environment; the table of min / median / max
with the command beside each figure is printed and written between the bench markers of
``README.md``."""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from tools import benches as registry
from tools.benches import Bench, Figure, filled, shown
from tools.checkout import PY, ROOT, say
from tools.errors import RegistryError

README = ROOT / "README.md"
BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"

#: what one run of a benchmark gives: each figure's value by label (None: not reported)
Values = dict[str, float | None]


def lookup(doc: object, keys: str) -> float | None:
    """The number at the dotted ``keys`` of a JSON document, or None (missing, not a number)."""
    for key in keys.split("."):
        if not isinstance(doc, dict) or key not in doc:
            return None
        doc = doc[key]
    return float(doc) if isinstance(doc, int | float) and not isinstance(doc, bool) else None


def run_bench(bench: Bench, quiet: bool) -> Values:
    """One run of ``bench`` in the environment: its setup, its command timed (``wall_s``), the
    figures read from the JSON it wrote."""
    if bench.needs and shutil.which(bench.needs) is None:
        say(f"{bench.needs} is not installed: {bench.name} left out", quiet)
        return {f.label: None for f in bench.figures}
    with tempfile.TemporaryDirectory(prefix="dev-bench-") as tmp:
        for setup in bench.setup:
            cmd = [str(PY), "-m", *filled(setup, tmp), "--quiet"]
            if subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL).returncode != 0:
                say(f"`{' '.join(setup)}` failed: {bench.name} left out", quiet)
                return {f.label: None for f in bench.figures}
        args = filled(bench.args, tmp)
        cmd = [str(PY), "-m", *args, *(["--quiet"] if quiet else [])]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(f"dev.py bench: `{' '.join(args)}` failed (exit {done.returncode})")
        doc = json.loads((Path(tmp) / bench.result).read_text())
    doc["wall_s"] = wall
    return {f.label: lookup(doc, f.keys) for f in bench.figures}


def _number(value: float) -> str:
    return f"{value:,.0f}" if 1000 <= abs(value) < 1e7 else f"{value:.3g}"


def render_table(rows: list[tuple[Bench, Figure, list[float | None]]], runs: int, note: str) -> str:
    """The README's table: one row per figure, min / median / max of its values (scaled to its
    unit; "-" where no run reported it) and the command."""
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
        command = shown(bench.args)
        lines.append(f"| {fig.label} | {' | '.join(cells)} | {fig.unit} | `{command}` |")
    return "\n".join(lines)


def replace_between_markers(text: str, table: str) -> str:
    """``text`` with everything between the bench markers replaced by ``table``."""
    pattern = re.compile(re.escape(BEGIN) + r".*?" + re.escape(END), re.DOTALL)
    if len(pattern.findall(text)) != 1:
        raise SystemExit(f"dev.py bench: README.md needs exactly one {BEGIN} ... {END} block")
    return pattern.sub(lambda _: f"{BEGIN}\n{table}\n{END}", text)


def main(argv: Sequence[str], quiet: bool, run: Callable[[Bench, bool], Values] = run_bench) -> int:
    """``dev.py bench ARGV``; ``run``: one run of one benchmark (:func:`run_bench`)."""
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
        help="length of hil bench's real-time run (default 60)",
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
    try:
        benches = registry.load(args.realtime_seconds, registry.BENCHES)
    except RegistryError as exc:
        print(f"dev.py bench: {exc}", file=sys.stderr)
        return 2
    if args.only:
        unknown = sorted(set(args.only) - {b.name for b in benches})
        if unknown:
            parser.error(f"--only: unknown {unknown}; known: {[b.name for b in benches]}")
        benches = tuple(b for b in benches if b.name in args.only)
    results: dict[str, list[Values]] = {b.name: [] for b in benches}
    total = len(benches) * args.runs
    step = 0
    t0 = time.monotonic()
    for i in range(args.runs):
        for b in benches:
            step += 1
            say(
                f"[{time.monotonic() - t0:6.0f} s] {step}/{total}: python -m "
                + shown(b.args)
                + f" (run {i + 1} of {args.runs})",
                quiet,
            )
            results[b.name].append(run(b, quiet))
    rows = [(b, f, [r[f.label] for r in results[b.name]]) for b in benches for f in b.figures]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    note = f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs, load average {load:.1f} at the end"
    text = render_table(rows, args.runs, note)
    print(text)
    if not args.no_readme:
        text_now = README.read_text(encoding="utf-8")
        README.write_text(replace_between_markers(text_now, text), encoding="utf-8")
        say(f"rewrote the table between the bench markers of {README}", quiet)
    return 0
