"""``python3 dev.py demo`` (its command) and ``python3 dev.py first-run``: the README's two
commands as a first run on a busy machine (issue 21)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from tools import testing
from tools.checkout import PY, ROOT, say

#: The tests a first run on a busy machine broke (issue 21) and those that start drives,
#: bridges and guests: selected by name, so that they are found wherever they live.
FIRST_RUN_TESTS = (
    "bridge_commands_run_or_refuse or loop_over_the_bus or other_pdo_numbers"
    " or sdo_configuration_while or (drive and test_process) or two_processes"
    " or compiles_before or waits_for_the_drive"
    " or candump or cangen or canbusload or lockstep_frames or persistent_pdo_loss"
)


def demo_command(rest: Sequence[str], quiet: bool) -> list[str]:
    """``python -m hil demo`` in the environment (default ``--out out/demo``)."""
    cmd = [str(PY), "-m", "hil", "demo", *(rest or ["--out", "out/demo"])]
    return [*cmd, "--quiet"] if quiet else cmd


def first_run(argv: Sequence[str], quiet: bool) -> int:
    """The README's two commands as a first run on a busy machine (issue 21): an empty numba
    cache (``NUMBA_CACHE_DIR`` a fresh folder, so every compiled function compiles) and
    every CPU kept busy by a spinning process beside them; the demo, then the tests that
    start drives and bridges (:data:`FIRST_RUN_TESTS`, or the pytest arguments given)."""
    parser = argparse.ArgumentParser(
        prog="python3 dev.py first-run",
        description="Run the demo and the start-up tests from an empty numba cache while "
        "busy processes keep every CPU loaded: what a fresh clone meets on a busy machine.",
    )
    parser.add_argument(
        "--busy",
        type=int,
        default=os.cpu_count() or 2,
        help="spinning processes beside them (default: one per CPU)",
    )
    parser.add_argument(
        "pytest_args",
        nargs=argparse.REMAINDER,
        help="pytest arguments (e.g. `tests -q` for the whole suite); default: the start-up tests",
    )
    # pytest's own options (-q, -k ...) pass through, first or not
    args, unknown = parser.parse_known_args(argv)
    if args.busy < 0:
        parser.error("--busy must be >= 0")
    pytest_args = [*unknown, *args.pytest_args] or ["-q", "-k", FIRST_RUN_TESTS]
    with tempfile.TemporaryDirectory(prefix="dev-first-run-") as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "numba-cache").mkdir()
        env = {"NUMBA_CACHE_DIR": str(tmp / "numba-cache")}
        spin = [sys.executable, "-c", "while True: pass"]
        busy = [subprocess.Popen(spin) for _ in range(args.busy)]
        say(f"empty numba cache {env['NUMBA_CACHE_DIR']}, {args.busy} busy processes", False)
        try:
            t0 = time.monotonic()
            demo = subprocess.run(
                demo_command(["--out", str(tmp / "demo")], quiet),
                cwd=ROOT,
                env={**os.environ, **env},
                stdout=subprocess.DEVNULL,
            ).returncode
            demo_s = time.monotonic() - t0
            say(f"first run: the demo exited {demo} after {demo_s:.0f} s", False)
            if demo != 0:
                return demo
            t0 = time.monotonic()
            code = testing.run(pytest_args, quiet, env)
            say(
                f"first run: the demo passed in {demo_s:.0f} s; the tests exited {code} "
                f"after {time.monotonic() - t0:.0f} s, both with {args.busy} busy processes",
                False,
            )
            return code
        finally:
            for p in busy:
                p.kill()
                p.wait()
