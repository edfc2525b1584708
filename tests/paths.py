"""Where the tests find the checkout's files."""

from __future__ import annotations

from pathlib import Path

#: the checkout
ROOT = Path(__file__).resolve().parents[1]
#: the shipped axis files and EDS files
CONFIG = ROOT / "config"
#: small data files of the tests' own (stored tool outputs, an encoder EDS)
DATA = Path(__file__).resolve().parent / "data"
