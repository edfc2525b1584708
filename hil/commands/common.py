"""Defaults shared by the ``python -m hil`` commands."""

from __future__ import annotations

PROG = "python -m hil"
