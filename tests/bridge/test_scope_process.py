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

import os
import select
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from tests.paths import ROOT

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


def start_bridge(tmp_path: Path) -> tuple[subprocess.Popen[str], str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [
        *(sys.executable, "-m", "bridge", "run", "--interface", "virtual", "--channel", "scope"),
        *("--axis", str(PAPER_AXIS), "--clock", "lockstep", "--seconds", "1"),
        *("--store", str(tmp_path / "store.json"), "--scope"),
    ]
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,  # its own process group: the test's Ctrl-C reaches it alone
    )
    assert proc.stderr is not None
    seen = []
    while True:
        line = proc.stderr.readline()
        seen.append(line)
        assert line, ("bridge run ended before its scope line", seen, proc.wait())
        if line.startswith("bridge run: scope at "):
            return proc, line.split()[4]


def answers(url: str) -> int:
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(url + "meta", timeout=BOUND_S) as r:
        return int(r.status)


@pytest.mark.parametrize("end", ["ctrl-c", "sigkill"])
def test_the_scope_server_ends_with_the_bridge(tmp_path: Path, end: str) -> None:
    proc, url = start_bridge(tmp_path)
    try:
        server = scope_server_pid(proc.pid)
        pidfd = os.pidfd_open(server)
        try:
            assert answers(url) == 200  # served while the bridge lives
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
