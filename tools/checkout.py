"""Where the checkout and its virtual environment are, and how ``dev.py`` speaks."""

from __future__ import annotations

import os
import sys
from pathlib import Path

#: the checkout (``dev.py``'s folder)
ROOT = Path(__file__).resolve().parents[1]
#: the project's virtual environment, made by ``dev.py``
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
#: its Python, which runs every command of the project
PY = BIN / ("python.exe" if os.name == "nt" else "python")


def say(text: str, quiet: bool) -> None:
    """One line ``dev.py: text`` on stderr, unless ``quiet``."""
    if not quiet:
        print(f"dev.py: {text}", file=sys.stderr, flush=True)
