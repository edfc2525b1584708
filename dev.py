#!/usr/bin/env python3
"""Create or reuse the project's virtual environment, then run the main job, tests or benchmarks.

    python3 dev.py [--quiet] demo [ARGS]    the main job (see README)
    python3 dev.py [--quiet] test [ARGS]    the whole test suite (pytest ARGS); where this
                                            kernel has no SocketCAN, the tests marked vcan
                                            run in a User-mode Linux guest on a real vcan0
    python3 dev.py [--quiet] bench [ARGS]   re-measure the README's figures (--help)
    python3 dev.py [--quiet] first-run      the demo and the start-up tests from an empty
                                            numba cache with every CPU busy (--help)
    python3 dev.py [--quiet] python ARGS    any command in the environment

Only the standard library is used here, so this runs on a fresh Python 3.11.
The environment lives in `.venv/`; it is (re)installed when `pyproject.toml` changes, with
pip's own progress shown (`--quiet`: none).
"""

# The sub-commands live in tools/ (testing.py, first_run.py, bench.py with the registry
# benches.toml); what is imported from there uses only the standard library as well.

from __future__ import annotations

import hashlib
import subprocess
import sys
import time
import venv
from pathlib import Path

# tools/ beside this file, also where the script's folder is not put on the path (python -P
# or -I, PYTHONSAFEPATH)
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parent))

from tools import bench, first_run, testing
from tools.checkout import PY, ROOT, VENV, say

STAMP = VENV / ".installed-from"


def _ensure_venv(quiet: bool) -> None:
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if PY.exists() and STAMP.exists() and STAMP.read_text().strip() == want:
        return
    t0 = time.monotonic()
    if not PY.exists():
        say(f"creating the virtual environment {VENV} (with pip, ~10 s)", quiet)
        venv.EnvBuilder(with_pip=True).create(VENV)
    say(
        "installing the project and its dependencies (numpy, scipy, numba, matplotlib, "
        "python-can, canopen, ...): the first time ~2 min, pip's progress follows",
        quiet,
    )
    pip = [str(PY), "-m", "pip", "install", "--disable-pip-version-check"]
    pip += ["-q"] if quiet else ["--progress-bar", "on" if sys.stderr.isatty() else "off"]
    subprocess.run([*pip, "-e", f"{ROOT}[test]"], check=True, stdout=sys.stderr)
    STAMP.write_text(want + "\n")
    say(f"environment ready ({time.monotonic() - t0:.0f} s)", quiet)


def main(argv: list[str]) -> int:
    quiet = bool(argv) and argv[0] in ("--quiet", "-q")
    if quiet:
        argv = argv[1:]
    if not argv or argv[0] not in {"demo", "test", "python", "bench", "first-run"}:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    _ensure_venv(quiet)
    verb, rest = argv[0], argv[1:]
    if verb == "bench":
        return bench.main(rest, quiet)
    if verb == "demo":
        cmd = first_run.demo_command(rest, quiet)
    elif verb == "test":
        return testing.run(rest, quiet)
    elif verb == "first-run":
        return first_run.first_run(rest, quiet)
    else:
        cmd = [str(PY), *rest]
    return subprocess.run(cmd, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
