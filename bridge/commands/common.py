"""Defaults shared by the ``python -m bridge`` commands."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAPER_AXIS = ROOT / "config" / "paper_axis.toml"
PROG = "python -m bridge"
