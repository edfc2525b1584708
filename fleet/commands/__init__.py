"""One module per ``python -m fleet`` command (see fleet/__main__.py)."""
