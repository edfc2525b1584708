"""A package's command line as the tests run it: in process (``main(argv)`` of its
``__main__``, argparse's own exits counted as exit statuses), or as a process whose output
is read line by line within a bound (:func:`next_line`)."""

from __future__ import annotations

import selectors
import subprocess
from collections.abc import Callable, Sequence

import pytest

Main = Callable[[Sequence[str]], int]


def exit_status(main: Main, argv: Sequence[str]) -> int:
    """The exit status of ``main(argv)``; argparse ends a bad command line with SystemExit."""
    try:
        return int(main(list(argv)))
    except SystemExit as exc:
        return int(exc.code or 0)


def refused_in_one_line(
    main: Main, argv: Sequence[str], capsys: pytest.CaptureFixture[str], code: int = 2
) -> str:
    """Run ``argv``; it must end with ``code`` and exactly one line on stderr, no traceback
    (the project's rule for bad input). Returns that line."""
    assert exit_status(main, argv) == code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def next_line(proc: subprocess.Popen[str], timeout_s: float) -> str:
    """The next stdout line of ``proc`` within ``timeout_s`` ("" if none)."""
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            return ""
    return proc.stdout.readline()
