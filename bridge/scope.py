"""The live scope of ``bridge run --scope [PORT]`` (issue 31 item 1): a page on 127.0.0.1 that
plots, while the loop runs, the following error, β (Fig. 5) and λ (eq. 15), the motor speed
and the load speed (times k_r, so both are motor rad/s), the motor torque, and the bridge's
state and stop reason, with a time window, pause and a CSV export of what is shown.

The loop never waits for it. After every cycle (``Bridge.after_cycle``) :meth:`Scope.cycle`
appends one tuple to a bounded :class:`collections.deque` (an append under the GIL, no lock,
no I/O); when the deque is full the oldest sample falls out. A thread of the scope drains
the deque every :data:`DRAIN_S` into a bounded history; samples the drain did not reach in
time are counted by the gaps in their sequence numbers (``dropped``). The page polls
``GET /data?after=SEQ`` (:mod:`http.server`, one thread per request) and gets the samples
after SEQ; a page that falls behind the history gets the newest ones and the gap counted.

Read-only: the server answers GET (and HEAD) on its own files and the data; every other
method gets 405 and nothing reaches the bridge. The plots are drawn by uPlot (MIT, vendored in
``bridge/scope_page/`` with its licence; docs/scope.md says why): the page needs no network.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import threading
from collections import deque
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import TYPE_CHECKING, Any, TextIO
from urllib.parse import parse_qs, urlsplit

from .errors import BridgeConfigError


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
    from .node import Bridge
    from .run import RunOptions

#: The ring between the loop and the drain: 8 s of 1 ms cycles.
RING_SAMPLES = 8192
#: What the server keeps for the page: 60 s of 1 ms cycles.
HISTORY_SAMPLES = 60_000
#: How often the drain empties the ring (wall clock), s.
DRAIN_S = 0.05
#: The most samples one answer carries (a page that asks for more gets the newest).
MAX_ANSWER = HISTORY_SAMPLES
#: The columns of a sample, in order (SI; positions in load units).
COLUMNS = (
    "seq",
    "t_s",
    "following_error",
    "beta_rad_s",
    "lambda",
    "motor_speed_rad_s",
    "load_position",
    "torque_nm",
    "state",
    "stop",
)
#: The interpreter's thread switch interval while the scope runs, s: the scope's threads share
#: the GIL with the loop; a loop thread that wakes while one of them runs Python gets the GIL
#: back within this (CPython's default, 5 ms, is five 1 ms cycles).
SWITCH_INTERVAL_S = 2e-4
#: The page's files: name -> content type.
FILES = {
    "index.html": "text/html; charset=utf-8",
    "scope.js": "text/javascript; charset=utf-8",
    "uPlot.iife.min.js": "text/javascript; charset=utf-8",
    "uPlot.min.css": "text/css; charset=utf-8",
    "uPlot.LICENSE": "text/plain; charset=utf-8",
}
#: The uPlot release vendored in bridge/scope_page (npm pack uplot@1.6.32).
UPLOT_VERSION = "1.6.32"

Sample = tuple[int, float, float, float, float, float, float, float, int, int]


class Scope:
    """The ring, the drain and the HTTP server of one run. port: 0 picks a free one.
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
        self.ring: deque[Sample] = deque(maxlen=RING_SAMPLES)
        self.history: deque[Sample] = deque(maxlen=HISTORY_SAMPLES)
        self.pushed = 0  # samples the loop handed over
        self.dropped = 0  # samples that never reached the history (ring overrun)
        self.meta: dict[str, Any] = {}
        self._stop_names: list[str] = []
        self._state_names: list[str] = []
        self._history_lock = threading.Lock()  # the drain vs. the request threads, never the loop
        self._next = threading.Event()
        self._stopped = threading.Event()
        self._prev_hook: Callable[[Bridge], None] | None = None
        self._bridge: Bridge | None = None
        self._drain_thread: threading.Thread | None = None
        self._switch_s: float | None = None
        try:
            self.server = ThreadingHTTPServer((host, port), _handler(self))
        except OSError as exc:
            raise BridgeConfigError(f"--scope {port}: cannot listen on {host}: {exc}") from None
        self.server.daemon_threads = True
        self._server_thread = threading.Thread(
            target=self.server.serve_forever, name="bridge-scope-http", daemon=True
        )

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}/"

    # --- the hooks ------------------------------------------------------------------------
    def attach(self, bridge: Bridge, options: RunOptions | None = None) -> None:
        """With the bridge built (``RunOptions.watch``): :meth:`follow` it and :meth:`start`."""
        self.follow(bridge, options)
        self.start()

    def start(self) -> None:
        """Start the drain and the server (once), say the address."""
        if self._drain_thread is not None:
            return
        self._switch_s = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_s, SWITCH_INTERVAL_S))
        self._drain_thread = threading.Thread(target=self._drain, name="bridge-scope", daemon=True)
        self._drain_thread.start()
        self._server_thread.start()
        self.stream.write(f"{self.command}: scope at {self.url} (read-only)\n")
        self.stream.flush()

    def follow(self, bridge: Bridge, options: RunOptions | None = None) -> None:
        """Chain :meth:`cycle` after the bridge's hook already there (the status line's); a
        bridge followed before is left (``hil demo``: one bridge per run, one scope)."""
        from .cycle import BridgeState, StopReason

        if self._bridge is not None and self._bridge.after_cycle in (self._chained, self.cycle):
            self._bridge.after_cycle = self._prev_hook

        c = bridge.controller
        p = c.params
        self._bridge = bridge
        self._state_names = [s.name for s in BridgeState]
        self._stop_names = [s.name for s in StopReason]
        kind = getattr(getattr(options, "axis", None), "kind", None)
        unit = "rad" if getattr(kind, "name", "LINEAR") == "ROTARY" else "m"
        self.meta = {
            "columns": list(COLUMNS),
            "load_unit": unit,
            "transmission_ratio": p.transmission_ratio,
            "beta_t_rad_s": c.regulator_config.beta_t_rad_s,
            "cycle_s": p.cycle_s,
            "states": self._state_names,
            "stops": self._stop_names,
            "uplot": UPLOT_VERSION,
        }
        self._prev_hook = bridge.after_cycle
        bridge.after_cycle = self._chained if self._prev_hook is not None else self.cycle

    def _chained(self, bridge: Bridge) -> None:
        prev = self._prev_hook
        if prev is not None:
            prev(bridge)
        self.cycle(bridge)

    def cycle(self, bridge: Bridge) -> None:
        """After every cycle, in the loop's thread: one tuple into the ring (never waits)."""
        c = bridge.controller
        self.pushed += 1
        self.ring.append(
            (
                self.pushed,
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
        )

    def close(self) -> None:
        """The run has ended: the last samples drained, the server and the drain stopped."""
        if self._bridge is not None and self._bridge.after_cycle in (self._chained, self.cycle):
            self._bridge.after_cycle = self._prev_hook
        self._stopped.set()
        if self._drain_thread is not None:
            self._drain_thread.join()
        if self._server_thread.is_alive():
            self.server.shutdown()
        self.server.server_close()
        if self._switch_s is not None:
            sys.setswitchinterval(self._switch_s)
            self._switch_s = None

    # --- the drain --------------------------------------------------------------------------
    def _drain(self) -> None:
        last = 0
        while True:
            stopping = self._stopped.wait(DRAIN_S)
            taken: list[Sample] = []
            while True:
                try:
                    taken.append(self.ring.popleft())
                except IndexError:
                    break
            if taken:
                gap = (
                    taken[0][0]
                    - last
                    - 1
                    + sum(b[0] - a[0] - 1 for a, b in itertools.pairwise(taken))
                )
                last = taken[-1][0]
                with self._history_lock:
                    self.dropped += gap
                    self.history.extend(taken)
            if stopping:
                return

    # --- what the page reads ----------------------------------------------------------------
    def answer(self, after: int) -> dict[str, Any]:
        """The samples with seq > ``after`` (at most :data:`MAX_ANSWER`, the newest), as
        columns; the counts; the latest state and stop reason by name."""
        with self._history_lock:
            n = len(self.history)
            # the history holds consecutive seq numbers except where samples were dropped:
            # scan back from the end
            i = n
            while i > 0 and self.history[i - 1][0] > after and n - i < MAX_ANSWER:
                i -= 1
            rows = [self.history[k] for k in range(i, n)]
            dropped = self.dropped
            latest = self.history[-1] if n else None
        cols: dict[str, list[Any]] = {name: [] for name in COLUMNS}
        for row in rows:
            for name, value in zip(COLUMNS, row, strict=True):
                cols[name].append(
                    value if not isinstance(value, float) or math.isfinite(value) else None
                )
        doc: dict[str, Any] = {
            "samples": cols,
            "pushed": self.pushed,
            "dropped": dropped,
            "last_seq": rows[-1][0] if rows else after,
            "running": not self._stopped.is_set(),
        }
        if latest is not None:
            doc["state"] = self._state_names[latest[8]]
            doc["stop"] = self._stop_names[latest[9]]
            if self._bridge is not None:
                doc["stop_message"] = self._bridge.controller.stop_message
        return doc


def _handler(scope: Scope) -> type[BaseHTTPRequestHandler]:
    page = resources.files("bridge") / "scope_page"

    class Handler(BaseHTTPRequestHandler):
        server_version = "bridge-scope"

        def log_message(self, format: str, *args: Any) -> None:
            pass  # the run's stderr is the user's; requests are not news

        def _send(self, status: HTTPStatus, body: bytes, kind: str, head: bool = False) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            if status is HTTPStatus.METHOD_NOT_ALLOWED:
                self.send_header("Allow", "GET, HEAD")
            self.end_headers()
            if not head:
                self.wfile.write(body)

        def do_GET(self, head: bool = False) -> None:
            url = urlsplit(self.path)
            name = url.path.lstrip("/") or "index.html"
            if name in FILES:
                body = (page / name).read_bytes()
                self._send(HTTPStatus.OK, body, FILES[name], head)
            elif name == "meta":
                self._send(HTTPStatus.OK, json.dumps(scope.meta).encode(), "application/json")
            elif name == "data":
                try:
                    after = int(parse_qs(url.query).get("after", ["0"])[0])
                except ValueError:
                    self._send(HTTPStatus.BAD_REQUEST, b"after: an integer\n", "text/plain")
                    return
                body = json.dumps(scope.answer(after), allow_nan=False).encode()
                self._send(HTTPStatus.OK, body, "application/json", head)
            else:
                self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain", head)

        def do_HEAD(self) -> None:
            self.do_GET(head=True)

        def _refuse(self) -> None:
            self._send(
                HTTPStatus.METHOD_NOT_ALLOWED, b"read-only: GET and HEAD only\n", "text/plain"
            )

        def __getattr__(self, name: str) -> Any:
            # every other method (POST, PUT, DELETE, PATCH, OPTIONS, anything): 405
            if name.startswith("do_"):
                return self._refuse
            raise AttributeError(name)

    return Handler
