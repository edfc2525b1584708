"""The live scope's server process (bridge.scope_server) ends with the bridge, however the
bridge ends, and never outlives it.

``bridge run --scope`` on a python-can virtual bus with ``--clock lockstep`` waits for a drive
that never answers (its lockstep start-up waits on the drive, not the clock): the bridge is
alive, its scope served, until the test ends it:

* Ctrl-C as a terminal sends it, to the whole process group: the server ignores SIGINT, the
  bridge ends its start-up (exit 1, as without the scope), and the server follows;
* SIGKILL of the bridge alone (no clean-up runs in it): the server reads end of file on its
  lifeline and exits.

The server is found as the bridge's child running ``bridge.scope_server`` (/proc), shown to
answer the page's address while the bridge lives, and its end is awaited on a pidfd (the
kernel's word that the process has exited), bounded only by a far backstop.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.paths import ROOT, checkout_env

PAPER_AXIS = ROOT / "config" / "paper_axis.toml"
BOUND_S = 300.0  # backstop of a wait for a process's state


def scope_server_pid(bridge_pid: int) -> int:
    """The pid of the scope server the bridge ``bridge_pid`` started (its child)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue  # ended meanwhile
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == bridge_pid and b"bridge.scope_server" in cmdline:
            found.append(int(entry.name))
    assert len(found) == 1, (bridge_pid, found)
    return found[0]


def ends(pidfd: int) -> bool:
    """True once the process of ``pidfd`` has exited (within the far backstop)."""
    ready, _, _ = select.select([pidfd], [], [], BOUND_S)
    return bool(ready)


@contextlib.contextmanager
def sigint_as_from_a_terminal() -> Iterator[None]:
    """Children started meanwhile get SIGINT at its default, as from a terminal. A program
    started under a shell's ``&`` without job control (a CI script, nohup) inherits SIGINT
    ignored and Python keeps it ignored: Ctrl-C would never reach the bridge's start-up (this
    test then hung for its 300 s in every full run started so). A handler here is reset to
    the default at the child's exec."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def start_bridge(
    tmp_path: Path, scope: bool = True, until: str = "bridge run: scope at "
) -> tuple[subprocess.Popen[str], str]:
    """``bridge run`` waiting for its drive, read up to the stderr line starting ``until``;
    returns the process and the scope's address ("" without it)."""
    env = checkout_env()
    argv = [
        *(sys.executable, "-m", "bridge", "run", "--interface", "virtual", "--channel", "scope"),
        *("--axis", str(PAPER_AXIS), "--clock", "lockstep", "--seconds", "1"),
        *("--store", str(tmp_path / "store.json"), *(["--scope"] if scope else [])),
    ]
    with sigint_as_from_a_terminal():
        proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            start_new_session=True,  # its own process group: the test's Ctrl-C reaches it alone
        )
    assert proc.stderr is not None
    seen, url = [], ""
    while True:
        line = proc.stderr.readline()
        seen.append(line)
        assert line, ("bridge run ended before its scope line", seen, proc.wait())
        if line.startswith("bridge run: scope at "):
            url = line.split()[4]
        if line.startswith(until):
            return proc, url


def answers(url: str) -> int:
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(url + "meta", timeout=BOUND_S) as r:
        return int(r.status)


@pytest.mark.parametrize("end", ["ctrl-c", "sigkill"])
def test_the_scope_server_ends_with_the_bridge(tmp_path: Path, end: str) -> None:
    proc, url = start_bridge(tmp_path)
    try:
        # served while the bridge lives; once it has answered, the server has surely finished
        # its exec (a process just past it may still show an empty command line)
        assert answers(url) == 200
        server = scope_server_pid(proc.pid)
        pidfd = os.pidfd_open(server)
        try:
            if end == "ctrl-c":
                os.killpg(proc.pid, signal.SIGINT)
                out, err = proc.communicate(timeout=BOUND_S)
                assert proc.returncode == 1, (out, err)
                assert "interrupted during the start-up" in err, err
                assert "scope's server ended" not in err, err
            else:
                proc.kill()
                proc.communicate(timeout=BOUND_S)
                assert proc.returncode == -signal.SIGKILL
            assert ends(pidfd), f"the scope server {server} outlived the bridge ({end})"
        finally:
            os.close(pidfd)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


#: the lockstep start-up's word that it waits for the drive (both runs reach it)
WAITING = "WARNING bridge: drive 2 does not answer yet"


def threads(pid: int) -> int:
    return len(list(Path(f"/proc/{pid}/task").iterdir()))


def test_the_scope_leaves_no_thread_in_the_bridge(tmp_path: Path) -> None:
    """The bridge's process has as many threads with the scope served as without it: the
    server and its drain are in the server's process."""
    counts = {}
    for scope in (False, True):
        proc, url = start_bridge(tmp_path, scope=scope, until=WAITING)
        try:
            counts[scope] = threads(proc.pid)
            if scope:
                assert answers(url) == 200
                server = scope_server_pid(proc.pid)
                assert threads(server) >= 2  # its parent watch and its drain live there
        finally:
            proc.kill()
            proc.communicate()
    assert counts[True] == counts[False], counts


def test_start_returns_once_the_server_has_drained_the_ring() -> None:
    """The loop starts only after the server's first drain (a lockstep loop runs faster than
    the wall and overran the ring before a server still importing had read anything: a page
    without the run's start). Three rings' worth pushed before ``start``: when it returns,
    the server has taken the ring once and written back what it could not keep."""
    import io

    from bridge.scope import RING_SAMPLES, Scope

    said = io.StringIO()
    scope = Scope(0, stream=said)
    try:
        for i in range(3 * RING_SAMPLES):
            scope.ring.push(i * 1e-3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0, 0)
        scope.start()
        assert scope.ring.dropped >= 2 * RING_SAMPLES, scope.ring.dropped
        assert said.getvalue() == f"bridge run: scope at {scope.url} (read-only)\n"
    finally:
        scope.close()
