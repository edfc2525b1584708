"""``python -m bridge probe``: read a drive and write its profile (the command lives in
:mod:`bridge.probe`, beside what it reads)."""

from ..probe import HELP, NAME, add_arguments, run

__all__ = ["HELP", "NAME", "add_arguments", "run"]
