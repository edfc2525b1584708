#!/usr/bin/env python3
"""Create or reuse the project's virtual environment, then run the main job or the tests.

    python3 dev.py demo [ARGS]   the main job (see README)
    python3 dev.py test [ARGS]   the whole test suite (pytest ARGS)
    python3 dev.py python ARGS   any command in the environment (e.g. `-m plant_sim bench`)

Only the standard library is used here, so this runs on a fresh Python 3.11.
The environment lives in `.venv/`; it is (re)installed when `pyproject.toml` changes.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".installed-from"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / ("python.exe" if os.name == "nt" else "python")


def _ensure_venv() -> None:
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if PY.exists() and STAMP.exists() and STAMP.read_text().strip() == want:
        return
    if not PY.exists():
        print(f"dev.py: creating virtual environment in {VENV}", file=sys.stderr)
        venv.EnvBuilder(with_pip=True).create(VENV)
    print("dev.py: installing the project and its dependencies", file=sys.stderr)
    pip = [str(PY), "-m", "pip", "install", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "-e", f"{ROOT}[test]"], check=True)
    STAMP.write_text(want + "\n")


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in {"demo", "test", "python"}:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    _ensure_venv()
    verb, rest = argv[0], argv[1:]
    if verb == "demo":
        cmd = [str(PY), "-m", "bridge", "demo", *(rest or ["--out", "out/demo"])]
    elif verb == "test":
        cmd = [str(PY), "-m", "pytest", *rest]
    else:
        cmd = [str(PY), *rest]
    return subprocess.run(cmd, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
