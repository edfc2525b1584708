"""A package's command line run in process, as the CLI tests run it: ``main(argv)`` of its
``__main__`` with argparse's own exits counted as exit statuses."""

from __future__ import annotations

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
