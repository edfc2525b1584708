"""The command-line framework every command of the project uses (standard library and tqdm).

* :mod:`.cli` -- commands as modules (``NAME``, ``HELP``, ``add_arguments``, ``run``), the
  parser and its argument types (bad input: one line, exit 2), the runner and its exit
  statuses, the check that an optional extra is installed;
* :mod:`.progress` -- progress on stderr: a bar on a terminal, a line per stage in a log.

It knows nothing of CAN, axes or the paper: the lowest floor (CONTRIBUTING.md).
"""
