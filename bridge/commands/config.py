"""``python -m bridge config``: commissioning over SDO (the command lives in
:mod:`bridge.commission.command`, beside its object access and DCF modules)."""

from ..commission.command import HELP, NAME, add_arguments, run

__all__ = ["HELP", "NAME", "add_arguments", "run"]
