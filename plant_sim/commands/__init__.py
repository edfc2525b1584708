"""One module per ``python -m plant_sim`` command (see plant_sim/__main__.py)."""
