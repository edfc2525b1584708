"""One module per ``python -m hil`` command (see hil/__main__.py, cmdline/cli.py)."""
