"""One module per ``python -m bridge`` command (see bridge/__main__.py, cmdline/cli.py)."""
