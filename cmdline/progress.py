"""Progress of long commands, one style for every command of the project.

On a terminal: a tqdm bar for counted work (simulations, cycles, cells). Not on a terminal
(a log file, a pipe, CI): one plain line per stage, ``[  12.3 s] PROG: what starts now``,
never a bar's carriage returns. ``quiet``: nothing at all. Progress goes to stderr, results
to stdout, so ``COMMAND > result.txt`` keeps the result clean.

Usage in a command::

    progress = Progress("plant_sim sweep", quiet=args.quiet)
    progress.stage("section X at 24 (k_v, δ) cells")
    with progress.bar(24, "sweep", unit="cell") as bar:
        for cell in cells:
            ...
            bar.update()

It lives next to :mod:`cmdline.cli` (the lowest package) so every package can use it.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Bar:
    """A counted stage: ``update(n)``, ``set_description(text)`` (a new sub-stage), ``close``.

    Compatible with what :func:`diagnosis.engine.diagnose` expects of a progress bar.
    """

    def __init__(self, progress: Progress, total: int | None, desc: str, unit: str) -> None:
        self._progress = progress
        self._desc = desc
        self.n = 0
        self._tqdm = None
        if progress.enabled and progress.terminal:
            from tqdm import tqdm

            tqdm.monitor_interval = 0  # no monitor thread: bars are updated from the work itself
            self._tqdm = tqdm(
                total=total, desc=desc, unit=unit, file=progress.stream, leave=False, delay=0.5
            )
        else:
            size = f" ({total} {unit}{'' if total == 1 else 's'})" if total else ""
            progress.stage(f"{desc}{size}")

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n
        if self._tqdm is not None:
            self._tqdm.update(n)

    def set_description(self, desc: str) -> None:
        if desc == self._desc:
            return
        self._desc = desc
        if self._tqdm is not None:
            self._tqdm.set_description(desc)
        else:
            self._progress.stage(desc)

    def close(self) -> None:
        if self._tqdm is not None:
            self._tqdm.close()
            self._tqdm = None


class Progress:
    """Progress reporting of one command run (see the module docstring).

    ``prog``: the command, printed before each stage line; ``quiet``: print nothing;
    ``stream``: where (default stderr); ``terminal``: force bar (True) or line (False) mode,
    default: whether ``stream`` is a terminal; ``clock``: seconds, injectable for tests.
    """

    def __init__(
        self,
        prog: str,
        quiet: bool = False,
        stream: TextIO | None = None,
        terminal: bool | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.prog = prog
        self.enabled = not quiet
        self.stream = stream if stream is not None else sys.stderr
        self.terminal = self.stream.isatty() if terminal is None else terminal
        self._clock = clock
        self._t0 = clock()

    def stage(self, text: str) -> None:
        """One line: elapsed time, the command, what starts now."""
        if not self.enabled:
            return
        elapsed = self._clock() - self._t0
        print(f"[{elapsed:6.1f} s] {self.prog}: {text}", file=self.stream, flush=True)

    def bar(self, total: int | None, desc: str, unit: str = "it") -> Bar:
        """A counted stage (a tqdm bar on a terminal, one stage line otherwise)."""
        return Bar(self, total, desc, unit)


#: A Progress that prints nothing (library calls without a command around them).
def silent() -> Progress:
    return Progress("", quiet=True)
