"""The live scope of ``bridge run --scope [PORT]`` (issue 31 item 1): a page on 127.0.0.1 that
plots, while the loop runs, the following error, β (Fig. 5) and λ (eq. 15), the motor speed
and the load speed (times k_r, so both are motor rad/s), the motor torque, and the bridge's
state and stop reason, with a time window, pause and a CSV export of what is shown.

The loop never waits for it, and nothing of the scope runs in the bridge's interpreter but the
loop's own append. After every cycle (``Bridge.after_cycle``) :meth:`Scope.cycle` writes one
sample into a ring in shared memory (:mod:`bridge.scope_ring`: two ``struct.pack_into``, no
lock, no system call). The page is served by a process of its own
(:mod:`bridge.scope_server`), which drains the ring, keeps the history and answers
``GET /data?after=SEQ`` and ``/meta``; it has no thread, lock or GIL in common with the loop.
The bridge binds the listening socket itself (its address is known, and a port in use is the
bridge's error, before the drive is configured) and hands it and the ring to the server as
inherited file descriptors. The server's standard input is a pipe only the bridge writes: when
the bridge ends, however it ends (SIGKILL included), the server reads end of file and exits.

Read-only: the server answers GET (and HEAD) on its own files and the data; every other
method gets 405 and nothing reaches the bridge. The plots are drawn by uPlot (MIT, vendored in
``bridge/scope_page/`` with its licence; docs/scope.md says why): the page needs no network.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from .errors import BridgeConfigError
from .scope_ring import COLUMNS, RingWriter


def port(text: str) -> int:
    """A ``--scope`` port: a TCP port, 0 for a free one."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: a TCP port 0..65535 (0: a free one)")
    return port


def add_scope_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--scope [PORT]`` of a command whose live scope serves ``what``."""
    parser.add_argument(
        "--scope",
        type=port,
        nargs="?",
        const=0,
        metavar="PORT",
        help=f"serve {what} on http://127.0.0.1:PORT/ (read-only; no PORT: a free one, its "
        "address on stderr; docs/scope.md)",
    )


if TYPE_CHECKING:
    from collections.abc import Callable

    from .node import Bridge
    from .run import RunOptions

#: The ring between the loop and the server: 8 s of 1 ms cycles (a power of two).
RING_SAMPLES = 8192
#: How long :meth:`Scope.close` lets the server take to exit after end of file before it is
#: killed, s (it exits at once; this only bounds the bridge's exit on a wedged host).
CLOSE_WAIT_S = 2.0
#: How long :meth:`Scope.start` waits for the server's first drain of the ring before the run
#: goes on without it, s (it takes 0.1-0.3 s; this only bounds a start on a wedged host).
READY_WAIT_S = 20.0
#: The uPlot release vendored in bridge/scope_page (npm pack uplot@1.6.32).
UPLOT_VERSION = "1.6.32"


class Scope:
    """The ring and the server process of one run. port: 0 picks a free one.
    stream: where the page's address is said (stderr)."""

    def __init__(
        self,
        port: int = 0,
        stream: TextIO | None = None,
        host: str = "127.0.0.1",
        command: str = "bridge run",
    ) -> None:
        if not 0 <= port <= 65535:
            raise BridgeConfigError(f"--scope {port}: a TCP port 0..65535 (0: a free one)")
        self.stream = stream if stream is not None else sys.stderr
        self.command = command
        self.meta: dict[str, Any] = {}
        self._prev_hook: Callable[[Bridge], None] | None = None
        self._bridge: Bridge | None = None
        self._message: str | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._closed = False
        self._dropped = 0
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            sock.listen(16)
        except OSError as exc:
            sock.close()
            raise BridgeConfigError(f"--scope {port}: cannot listen on {host}: {exc}") from None
        self._sock: socket.socket | None = sock
        self.address: tuple[str, int] = sock.getsockname()[:2]
        self.ring = RingWriter(RING_SAMPLES)
        self._push = self.ring.push

    @property
    def url(self) -> str:
        host, port = self.address
        return f"http://{host}:{port}/"

    @property
    def pushed(self) -> int:
        """Samples the loop handed over."""
        return self.ring.seq

    @property
    def dropped(self) -> int:
        """Samples that never reached the server's history (ring overrun), as it counted."""
        return self._dropped if self._closed else self.ring.dropped

    @property
    def server_pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    # --- the hooks ------------------------------------------------------------------------
    def attach(self, bridge: Bridge, options: RunOptions | None = None) -> None:
        """With the bridge built (``RunOptions.watch``): :meth:`follow` it and :meth:`start`."""
        self.follow(bridge, options)
        self.start()

    def start(self) -> None:
        """Start the server process (once), wait (at most :data:`READY_WAIT_S`) until it has
        drained the ring once, say the address."""
        if self._proc is not None or self._sock is None:
            return
        ring_fd, listen_fd = self.ring.fd, self._sock.fileno()
        root = str(Path(__file__).resolve().parent.parent)  # where `bridge` imports from
        env = dict(os.environ)
        env["PYTHONPATH"] = root + (":" + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        argv = [sys.executable, "-m", "bridge.scope_server"]
        argv += ["--ring-fd", str(ring_fd), "--listen-fd", str(listen_fd)]
        self._proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,  # the lifeline: end of file when the bridge ends
            stdout=subprocess.PIPE,  # one line: "ready" after its first drain
            pass_fds=(ring_fd, listen_fd),
            env=env,
        )
        self._sock.close()  # the server's now
        self._sock = None
        late = self._wait_ready(self._proc)
        self.stream.write(f"{self.command}: scope at {self.url} (read-only){late}\n")
        self.stream.flush()

    @staticmethod
    def _wait_ready(proc: subprocess.Popen[bytes]) -> str:
        """Wait for the server's "ready" line (bounded), close the pipe; '' when it came,
        else what the page may miss."""
        assert proc.stdout is not None
        out = proc.stdout
        try:
            ready, _, _ = select.select([out], [], [], READY_WAIT_S)
            line = os.read(out.fileno(), 64) if ready else None
        finally:
            out.close()
        if line is None:
            return (
                f"; its server was not ready after {READY_WAIT_S:g} s, "
                "the page may miss the run's start"
            )
        if not line.startswith(b"ready"):
            return "; its server ended at its start (the page is not served)"
        return ""

    def follow(self, bridge: Bridge, options: RunOptions | None = None) -> None:
        """Chain :meth:`cycle` after the bridge's hook already there (the status line's); a
        bridge followed before is left (``hil demo``: one bridge per run, one scope)."""
        from .cycle import BridgeState, StopReason

        if self._bridge is not None and self._bridge.after_cycle in (self._chained, self.cycle):
            self._bridge.after_cycle = self._prev_hook

        c = bridge.controller
        p = c.params
        self._bridge = bridge
        kind = getattr(getattr(options, "axis", None), "kind", None)
        unit = "rad" if getattr(kind, "name", "LINEAR") == "ROTARY" else "m"
        self.meta = {
            "columns": list(COLUMNS),
            "load_unit": unit,
            "transmission_ratio": p.transmission_ratio,
            "beta_t_rad_s": c.regulator_config.beta_t_rad_s,
            "cycle_s": p.cycle_s,
            "states": [s.name for s in BridgeState],
            "stops": [s.name for s in StopReason],
            "uplot": UPLOT_VERSION,
        }
        self.ring.set_meta(json.dumps(self.meta).encode())
        self._message = c.stop_message
        self.ring.set_message(c.stop_message)
        self._prev_hook = bridge.after_cycle
        bridge.after_cycle = self._chained if self._prev_hook is not None else self.cycle

    def _chained(self, bridge: Bridge) -> None:
        prev = self._prev_hook
        if prev is not None:
            prev(bridge)
        self.cycle(bridge)

    def cycle(self, bridge: Bridge) -> None:
        """After every cycle, in the loop's thread: one sample into the shared ring (never
        waits); the stop message too when it has changed (rarely)."""
        c = bridge.controller
        self._push(
            c.now_s,
            c.following_error,
            c.vibration_level,
            c.switching_factor,
            c.motor_speed_rad_s,
            c.load_position,
            c.motor_torque_nm,
            c.state.value,
            c.stop_reason.value,
        )
        message = c.stop_message
        if message is not self._message:
            self._message = message
            self.ring.set_message(message)

    def close(self) -> None:
        """The run has ended: the server told (end of file) and gone, the ring unmapped."""
        if self._closed:
            return
        if self._bridge is not None and self._bridge.after_cycle in (self._chained, self.cycle):
            self._bridge.after_cycle = self._prev_hook
        self.ring.mark_closed()
        self._dropped = self.ring.dropped
        self._closed = True
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        proc = self._proc
        if proc is not None:
            assert proc.stdin is not None
            proc.stdin.close()
            try:
                proc.wait(timeout=CLOSE_WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if proc.returncode > 0:  # a crash (its traceback is on stderr); not a signal
                self.stream.write(
                    f"{self.command}: the scope's server ended with code {proc.returncode}\n"
                )
        self.ring.close()
