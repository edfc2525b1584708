"""Developer tools, not installed (floor 5): what ``dev.py`` runs and the measuring tools.

``dev.py`` keeps the virtual environment and the dispatch of its sub-commands; the rest is
here, and every module ``dev.py`` imports uses only the standard library (it runs them on a
bare Python 3.11, before ``.venv/`` exists):

* :mod:`tools.checkout`: where the checkout and its environment are, ``dev.py``'s messages;
* :mod:`tools.testing`: ``dev.py test``, the host/guest split of the tests marked vcan;
* :mod:`tools.first_run`: ``dev.py demo``'s command and ``dev.py first-run``;
* :mod:`tools.benches`: the benchmark registry, read from ``tools/benches.toml``;
* :mod:`tools.bench`: ``dev.py bench``, running the benchmarks and the README's table;
* :mod:`tools.errors`: the package's exception root.

``lockstep_instructions.py`` is a script of its own (``python tools/lockstep_instructions.py``).
"""
