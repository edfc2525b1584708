"""The live scope's server: a process of its own beside the bridge (docs/scope.md).

``python -m bridge.scope_server --ring-fd N --listen-fd M`` is started by
:class:`bridge.scope.Scope` with two inherited file descriptors: the shared-memory ring the
loop writes (:mod:`bridge.scope_ring`) and the listening TCP socket the bridge bound (so the
bridge knows the address, and a port in use is its error, before this process runs). Its
standard input is a pipe whose only writer is the bridge: end of file means the bridge has
ended (closed the scope, exited or been killed), and this process exits at once.

A thread drains the ring every :data:`DRAIN_S` into a bounded history; the HTTP server
(:class:`http.server.ThreadingHTTPServer`) answers the page from it. Read-only: GET and HEAD
on the page's files, ``/meta`` and ``/data``; every other method gets 405. Nothing here can
reach the bus: this process holds the ring and a socket, nothing else of the bridge.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import socket
import sys
import threading
import time
from collections import deque
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from .scope_ring import COLUMNS, RingReader, Sample

#: What the server keeps for the page: 60 s of 1 ms cycles.
HISTORY_SAMPLES = 60_000
#: How often the drain empties the ring (wall clock), s.
DRAIN_S = 0.05
#: The most samples one answer carries (a page that asks for more gets the newest).
MAX_ANSWER = HISTORY_SAMPLES
#: The page's files: name -> content type.
FILES = {
    "index.html": "text/html; charset=utf-8",
    "scope.js": "text/javascript; charset=utf-8",
    "uPlot.iife.min.js": "text/javascript; charset=utf-8",
    "uPlot.min.css": "text/css; charset=utf-8",
    "uPlot.LICENSE": "text/plain; charset=utf-8",
}


class History:
    """The samples drained from the ring, and the page's answers from them."""

    def __init__(self, ring: RingReader, size: int = HISTORY_SAMPLES) -> None:
        self.ring = ring
        self.rows: deque[Sample] = deque(maxlen=size)
        self._lock = threading.Lock()  # the drain vs. the request threads
        self._meta = b"{}"
        self._meta_doc: dict[str, Any] = {}

    def drain(self) -> None:
        with self._lock:
            self.rows.extend(self.ring.take())

    def meta(self) -> dict[str, Any]:
        raw = self.ring.meta()
        if raw and raw != self._meta:
            self._meta, self._meta_doc = raw, json.loads(raw)
        return self._meta_doc

    def answer(self, after: int) -> dict[str, Any]:
        """The samples with seq > ``after`` (at most :data:`MAX_ANSWER`, the newest), as
        columns; the counts; the latest state and stop reason by name."""
        self.drain()
        with self._lock:
            n = len(self.rows)
            # consecutive seq numbers except where samples were dropped: scan back from the end
            i = n
            while i > 0 and self.rows[i - 1][0] > after and n - i < MAX_ANSWER:
                i -= 1
            rows = [self.rows[k] for k in range(i, n)]
            latest = self.rows[-1] if n else None
            dropped = self.ring.dropped
        cols: dict[str, list[Any]] = {name: [] for name in COLUMNS}
        for row in rows:
            for name, value in zip(COLUMNS, row, strict=True):
                cols[name].append(
                    value if not isinstance(value, float) or math.isfinite(value) else None
                )
        doc: dict[str, Any] = {
            "samples": cols,
            "pushed": self.ring.write_seq,
            "dropped": dropped,
            "last_seq": rows[-1][0] if rows else after,
            "running": not self.ring.closed,
        }
        meta = self.meta()
        if latest is not None and meta:
            doc["state"] = meta["states"][latest[8]]
            doc["stop"] = meta["stops"][latest[9]]
            doc["stop_message"] = self.ring.message()
        return doc


def handler(history: History) -> type[BaseHTTPRequestHandler]:
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
                body = json.dumps(history.meta()).encode()
                self._send(HTTPStatus.OK, body, "application/json", head)
            elif name == "data":
                try:
                    after = int(parse_qs(url.query).get("after", ["0"])[0])
                except ValueError:
                    self._send(HTTPStatus.BAD_REQUEST, b"after: an integer\n", "text/plain", head)
                    return
                body = json.dumps(history.answer(after), allow_nan=False).encode()
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


def _drain(history: History) -> None:
    history.drain()
    _say_ready()
    while True:
        time.sleep(DRAIN_S)
        history.drain()


def _say_ready() -> None:
    """One line on standard output once the ring is drained for the first time, then
    standard output is closed (the bridge reads that line, and nothing after it, so nothing
    can fill the pipe): the bridge starts its loop only then (:meth:`bridge.scope.Scope.start`),
    so a loop faster than the wall (lockstep) cannot overrun the ring before the first drain."""
    with contextlib.suppress(OSError):
        os.write(1, b"ready\n")
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.close(null)


def _watch_parent() -> None:
    """End of file on stdin: the bridge has ended (closed, exited or killed): exit now,
    whatever a request thread is doing."""
    try:
        while sys.stdin.buffer.read(4096):
            pass
    finally:
        os._exit(0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bridge.scope_server", description=__doc__)
    parser.add_argument("--ring-fd", type=int, required=True)
    parser.add_argument("--listen-fd", type=int, required=True)
    args = parser.parse_args(argv)
    # Ctrl-C reaches the whole foreground group: the bridge stops the axis and ends, and this
    # process ends with it (stdin's end of file), serving the page until then
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, name="scope-parent", daemon=True).start()
    history = History(RingReader(args.ring_fd))
    os.close(args.ring_fd)  # the mapping stays
    sock = socket.socket(fileno=args.listen_fd)
    server = ThreadingHTTPServer(sock.getsockname()[:2], handler(history), bind_and_activate=False)
    server.socket.close()
    server.socket = sock
    server.daemon_threads = True
    threading.Thread(target=_drain, args=(history,), name="scope-drain", daemon=True).start()
    server.serve_forever()
    return 0


if __name__ == "__main__":
    sys.exit(main())
