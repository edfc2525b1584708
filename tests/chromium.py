"""A page opened in headless Chromium (Debian's ``chromium``), driven over the DevTools
protocol on a pipe (``--remote-debugging-pipe``: the browser reads commands from its fd 3 and
writes answers and events to its fd 4, each a JSON text ended by a NUL byte; no port, no
network, the standard library only).

:func:`open_page` loads a URL in a fresh profile and returns a :class:`PageCheck`: every
console message of level error, every uncaught exception, every log entry of level error
(a resource that failed to load, a blocked request), every request the page made, the
values of JavaScript expressions evaluated in it, and a screenshot of the whole page.
:func:`chromium_problem` says why no page can be opened here (no browser installed).
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Debian's package installs the browser as /usr/bin/chromium (``apt-get install chromium``).
CANDIDATES = ("chromium", "chromium-browser", "google-chrome")
#: Launch flags that work in containers and CI runners (no sandbox, no GPU, nothing fetched).
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--hide-scrollbars",
    "--mute-audio",
    "--remote-debugging-pipe",
)
#: Far backstop for any one answer of the browser: only a hung browser reaches it.
BACKSTOP_S = 180.0


class ChromiumError(RuntimeError):
    """The browser did not start, answer, or load the page."""


def chromium_binary() -> str | None:
    for name in CANDIDATES:
        found = shutil.which(name)
        if found:
            return found
    return None


def chromium_problem() -> str | None:
    """None when a page can be opened; otherwise why not (a skip reason)."""
    if chromium_binary() is None:
        return (
            "no headless Chromium here (Debian: apt-get install chromium; CI installs it "
            "in .ci/run)"
        )
    return None


@dataclass
class PageCheck:
    """What the browser saw of one page."""

    url: str
    console_errors: list[str] = field(default_factory=list)
    exceptions: list[str] = field(default_factory=list)
    log_errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)
    values: dict[str, Any] = field(default_factory=dict)
    screenshot_png: bytes = b""

    @property
    def errors(self) -> list[str]:
        """Everything the browser's console shows as an error."""
        return self.console_errors + self.exceptions + self.log_errors

    def external_requests(self, allowed: Sequence[str] = ("file:", "data:", "about:")) -> list:
        """Requests to anything but the page's own file and data URIs (the network)."""
        return [u for u in self.requests if not u.startswith(tuple(allowed))]


class _Pipe:
    """The DevTools protocol over the browser's two pipes."""

    def __init__(self, to_browser: int, from_browser: int) -> None:
        self._out = to_browser
        self._in = from_browser
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict[str, Any]] = []

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Send one command and return its result (events that arrive meanwhile are kept)."""
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        data = json.dumps(message).encode() + b"\0"
        while data:
            data = data[os.write(self._out, data) :]
        while True:
            answer = self._receive()
            if answer.get("id") == self._next_id:
                if "error" in answer:
                    raise ChromiumError(f"{method}: {answer['error'].get('message')}")
                return answer.get("result", {})
            self.events.append(answer)

    def wait_for(self, method: str) -> dict[str, Any]:
        """The first event ``method`` (kept ones first), its params."""
        for event in self.events:
            if event.get("method") == method:
                return event.get("params", {})
        while True:
            event = self._receive()
            self.events.append(event)
            if event.get("method") == method:
                return event.get("params", {})

    def _receive(self) -> dict[str, Any]:
        deadline = time.monotonic() + BACKSTOP_S
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self._in], [], [], max(left, 0.0))
            if not ready:
                raise ChromiumError(f"no answer from the browser within {BACKSTOP_S:g} s")
            chunk = os.read(self._in, 1 << 16)
            if not chunk:
                raise ChromiumError("the browser closed its DevTools pipe (it exited)")
            self._buffer += chunk
        text, _, self._buffer = self._buffer.partition(b"\0")
        return json.loads(text)


def _collect(page: PageCheck, events: list[dict[str, Any]]) -> None:
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            args = params.get("args", [])
            page.console_errors.append(
                " ".join(str(a.get("value", a.get("description", ""))) for a in args)
            )
        elif method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            exc = details.get("exception", {})
            page.exceptions.append(exc.get("description") or details.get("text", "exception"))
        elif method == "Log.entryAdded":
            entry = params.get("entry", {})
            if entry.get("level") == "error":
                page.log_errors.append(f"{entry.get('text')} ({entry.get('url', '')})")
        elif method == "Network.requestWillBeSent":
            page.requests.append(params.get("request", {}).get("url", ""))


def open_page(
    url: str,
    expressions: Sequence[str] = (),
    width: int = 1280,
    height: int = 900,
    full_page: bool = True,
    prefix: Sequence[str] = (),
) -> PageCheck:
    """Load ``url`` in a fresh headless Chromium, wait for its load event, evaluate
    ``expressions`` (JavaScript; their JSON values in :attr:`PageCheck.values`) and take a
    screenshot (the whole page, or the first ``width`` x ``height`` pixels). ``prefix``: a
    command the browser runs under (``ip netns exec NAME``: a page served in a namespace)."""
    binary = chromium_binary()
    if binary is None:
        raise ChromiumError(chromium_problem() or "no chromium")
    page = PageCheck(url)
    with (
        tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile,
        tempfile.TemporaryFile() as log,
    ):
        cmd_r, cmd_w = os.pipe()  # commands: we write, the browser reads on its fd 3
        ev_r, ev_w = os.pipe()  # answers: the browser writes on its fd 4, we read

        def child_fds() -> None:
            # dup2 clears close-on-exec on 3 and 4; copies above 4 first, so that neither
            # pipe end lands on the other's number
            high_r = fcntl.fcntl(cmd_r, fcntl.F_DUPFD_CLOEXEC, 10)
            high_w = fcntl.fcntl(ev_w, fcntl.F_DUPFD_CLOEXEC, 10)
            os.dup2(high_r, 3)
            os.dup2(high_w, 4)

        proc = subprocess.Popen(
            [
                *prefix,
                binary,
                *FLAGS,
                f"--user-data-dir={profile}",
                f"--window-size={width},{height}",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=log,
            preexec_fn=child_fds,  # only dup2 before exec
            # subprocess would close fds 3 and 4 after preexec_fn; every other descriptor of
            # this process is close-on-exec (PEP 446)
            close_fds=False,
            start_new_session=True,
        )
        os.close(cmd_r)
        os.close(ev_w)
        pipe = _Pipe(cmd_w, ev_r)
        try:
            target = pipe.send("Target.createTarget", {"url": "about:blank"})["targetId"]
            session = pipe.send("Target.attachToTarget", {"targetId": target, "flatten": True})[
                "sessionId"
            ]
            for domain in ("Runtime", "Log", "Network", "Page"):
                pipe.send(f"{domain}.enable", session=session)
            pipe.send(
                "Emulation.setDeviceMetricsOverride",
                {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
                session=session,
            )
            pipe.events.clear()
            pipe.send("Page.navigate", {"url": url}, session=session)
            pipe.wait_for("Page.loadEventFired")
            for expr in expressions:
                result = pipe.send(
                    "Runtime.evaluate",
                    {"expression": expr, "returnByValue": True, "awaitPromise": True},
                    session=session,
                )
                if "exceptionDetails" in result:
                    raise ChromiumError(f"{expr}: {result['exceptionDetails'].get('text')}")
                page.values[expr] = result.get("result", {}).get("value")
            shot: dict[str, Any] = {"format": "png"}
            if full_page:
                size = pipe.send("Page.getLayoutMetrics", session=session)["cssContentSize"]
                shot["captureBeyondViewport"] = True
                shot["clip"] = {
                    "x": 0,
                    "y": 0,
                    "width": max(width, int(size["width"])),
                    "height": int(size["height"]),
                    "scale": 1,
                }
            page.screenshot_png = base64.b64decode(
                pipe.send("Page.captureScreenshot", shot, session=session)["data"]
            )
            _collect(page, pipe.events)
            with contextlib.suppress(ChromiumError):  # it may exit before it answers
                pipe.send("Browser.close")
        except ChromiumError as exc:
            log.seek(0)
            tail = [ln for ln in log.read().decode(errors="replace").splitlines() if ln][-3:]
            raise ChromiumError(f"{exc}; the browser's last words: {' | '.join(tail)}") from exc
        finally:
            os.close(cmd_w)
            try:
                proc.wait(timeout=BACKSTOP_S)
            except subprocess.TimeoutExpired:
                proc.kill()  # the browser we started, by its own handle
                proc.wait()
            os.close(ev_r)
    return page


def write_screenshot(page: PageCheck, path: str | Path) -> Path:
    out = Path(path)
    out.write_bytes(page.screenshot_png)
    return out
