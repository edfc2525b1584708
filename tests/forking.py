"""Processes to kill, started cheaply: a warm process (:class:`Forker`) imports what they need
once and forks one child per trial, so a test can kill fifty of them with SIGKILL in the time
fifty fresh interpreters would take to import numpy, numba and matplotlib.

The forker runs ``python -m tests.forking MODULE[:WARM]...`` (its own process; it imports each
module and calls its function WARM, if named, once; a fork copies only the thread that forks,
so it forks only while it has no other thread). It reads one JSON line per trial from stdin,
``{"call": "MODULE:FUNCTION", "args": [...], "out": "DIR"}``, forks, prints the child's pid
and, when the child has ended, how (``{"pid": P, "status": "exit 0" | "signal 9"}``). The
child runs ``FUNCTION(*args)`` with stdout and stderr in ``DIR/child.out`` and
``DIR/child.err`` and ends with its return value (1 and the traceback on an exception).
"""

from __future__ import annotations

import importlib
import json
import os
import selectors
import signal
import subprocess
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path

from tests.paths import ROOT
from virtual_bus.closing import Closing

#: Backstop of a wait for the forker's answer (far beyond a cold import on a busy machine).
ANSWER_BACKSTOP_S = 900.0


class Forker(Closing):
    """The warm process (see the module docstring); ``with`` ends it."""

    def __init__(self, modules: Sequence[str], env: dict[str, str] | None = None) -> None:
        env = {**(env or os.environ), "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.forking", *modules],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            env=env,
        )
        ready = self._answer()
        if ready.get("ready") is not True:
            raise RuntimeError(f"the forker did not start: {ready}")

    def _answer(self, timeout_s: float = ANSWER_BACKSTOP_S) -> dict[str, object]:
        assert self.proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            if not sel.select(timeout_s):
                raise TimeoutError("the forker did not answer")
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the forker ended (exit {self.proc.wait()})")
        return json.loads(line)

    def start(self, call: str, args: Sequence[object], out: Path) -> int:
        """Fork a child running ``call(*args)``; returns its pid."""
        assert self.proc.stdin is not None
        out.mkdir(parents=True, exist_ok=True)
        self.proc.stdin.write(json.dumps({"call": call, "args": list(args), "out": str(out)}))
        self.proc.stdin.write("\n")
        self.proc.stdin.flush()
        answer = self._answer()
        if "pid" not in answer:
            raise RuntimeError(f"the forker could not fork: {answer}")
        return int(answer["pid"])  # type: ignore[arg-type]

    def ended(self) -> bool:
        """Whether the child's end has been reported (without waiting)."""
        assert self.proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            return bool(sel.select(0))

    def wait(self) -> str:
        """How the child ended: ``exit N`` or ``signal N``."""
        return str(self._answer()["status"])

    def close(self) -> None:
        """Ask the forker to end (close its stdin) and reap it; ``with`` calls this."""
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _child(request: dict[str, object]) -> int:
    out = Path(str(request["out"]))
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    for fd, name in ((1, "child.out"), (2, "child.err")):
        os.dup2(os.open(out / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), fd)
    sys.stdin = open(0, closefd=False)  # noqa: SIM115 - the child's, until os._exit
    module, _, function = str(request["call"]).partition(":")
    try:
        result = getattr(importlib.import_module(module), function)(*request["args"])  # type: ignore[misc]
        code = int(result or 0)
    except BaseException:
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    return code


def main(modules: Sequence[str]) -> None:
    for module in modules:
        name, _, warm = module.partition(":")
        imported = importlib.import_module(name)
        if warm:  # a warm-up call, its output to stderr: compiled code and caches loaded once
            stdout, sys.stdout = sys.stdout, sys.stderr
            try:
                getattr(imported, warm)()
            finally:
                sys.stdout = stdout
    say = sys.stdout
    say.write(json.dumps({"ready": True}) + "\n")
    say.flush()
    for line in sys.stdin:
        request = json.loads(line)
        if _threads() != 1:  # a fork copies one thread: the others' locks would stay taken
            say.write(json.dumps({"error": f"{_threads()} threads in the forker"}) + "\n")
            say.flush()
            continue
        say.flush()
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                signal.signal(signal.SIGINT, signal.SIG_DFL)
                code = _child(request)
            finally:
                os._exit(code)
        say.write(json.dumps({"pid": pid}) + "\n")
        say.flush()
        _, status = os.waitpid(pid, 0)
        how = (
            f"signal {os.WTERMSIG(status)}"
            if os.WIFSIGNALED(status)
            else f"exit {os.WEXITSTATUS(status)}"
        )
        say.write(json.dumps({"pid": pid, "status": how}) + "\n")
        say.flush()


if __name__ == "__main__":
    main(sys.argv[1:])
