"""Where the tests find the checkout's files."""

from __future__ import annotations

import os
from pathlib import Path

#: the checkout
ROOT = Path(__file__).resolve().parents[1]
#: the shipped axis files and EDS files
CONFIG = ROOT / "config"
#: small data files of the tests' own (stored tool outputs, an encoder EDS)
DATA = Path(__file__).resolve().parent / "data"


def checkout_env() -> dict[str, str]:
    """This process's environment with the checkout on ``PYTHONPATH``: what a program the
    tests start (``python -m bridge ...``) needs to import the checkout's packages."""
    return {**os.environ, "PYTHONPATH": str(ROOT)}
