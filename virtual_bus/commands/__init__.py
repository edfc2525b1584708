"""One module per ``python -m virtual_bus`` command (see cmdline/cli.py)."""
