"""One module per ``python -m virtual_bus`` command (see virtual_bus/cli.py)."""
