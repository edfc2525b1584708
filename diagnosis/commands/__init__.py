"""One module per ``python -m diagnosis`` command (see diagnosis/__main__.py)."""
