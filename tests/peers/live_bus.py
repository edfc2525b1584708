"""Programs on a live SocketCAN bus for the tests under ``tests/peers``: the simulated drive
and ``bridge run`` as processes of their own, can-utils beside them, candump logs parsed.

Every wait here waits for a state of a program (a line it printed, a frame it recorded) and
is bounded by that program's life: it ends when the program does. :data:`STATE_BOUND_S` is
only the backstop against a program that hangs without dying; it is far beyond a cold numba
compile on a loaded 2-core machine (a drive compiles before its boot-up message).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from tests.paths import ROOT, checkout_env

STATE_BOUND_S = 900.0


def need_programs(*names: str) -> None:
    """Skip (with the package to install) unless every program is on PATH."""
    missing = [n for n in names if shutil.which(n) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (apt-get install can-utils)")


def env() -> dict[str, str]:
    """The environment of a child process that imports this checkout's packages."""
    return {**checkout_env(), "PYTHONUNBUFFERED": "1"}


class Program:
    """A child process whose standard output is read line by line by a thread of its own;
    :meth:`wait_for` waits until its lines satisfy a condition, as long as it runs."""

    def __init__(self, argv: Sequence[str], name: str) -> None:
        self.name = name
        self.argv = list(argv)
        self.lines: list[str] = []
        self._changed = threading.Condition()
        self.proc = subprocess.Popen(
            self.argv,
            cwd=ROOT,
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        self._err: list[str] = []
        self._threads = [
            threading.Thread(target=self._read, name=f"{name}-stdout", daemon=True),
            threading.Thread(target=self._read_err, name=f"{name}-stderr", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    def _read_err(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            with self._changed:
                self._err.append(line.rstrip("\n"))
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    @property
    def stderr(self) -> str:
        return "\n".join(self._err)

    def wait_for(self, condition: Callable[[list[str]], bool], what: str) -> None:
        """Until ``condition(lines)``; fails (naming ``what``) if the program ends first."""
        self._wait(self.lines, 0, condition, what)

    def wait_for_err(self, condition: Callable[[list[str]], bool], what: str) -> None:
        """:meth:`wait_for` on the lines of standard error (a program's log)."""
        self._wait(self._err, 1, condition, what)

    def _wait(
        self,
        lines: list[str],
        reader: int,
        condition: Callable[[list[str]], bool],
        what: str,
    ) -> None:
        """The one wait of :meth:`wait_for` and :meth:`wait_for_err`: ``lines`` is the list
        that ``self._threads[reader]`` fills; ends when the program and that reader are done."""
        deadline = time.monotonic() + STATE_BOUND_S
        with self._changed:
            while not condition(lines):
                if self.proc.poll() is not None and not self._threads[reader].is_alive():
                    raise AssertionError(
                        f"{self.name} ended (exit {self.proc.returncode}) before {what}; "
                        f"stderr: {self.stderr[-1500:]}"
                    )
                if time.monotonic() > deadline:
                    raise AssertionError(f"{self.name}: no {what} in {STATE_BOUND_S:g} s")
                self._changed.wait(1.0)

    def finish(self) -> int:
        """Wait for the program's own end (bounded like :meth:`wait_for`)."""
        try:
            code = self.proc.wait(STATE_BOUND_S)
        finally:
            self.stop()
        return code

    def stop(self, sig: int = signal.SIGTERM) -> int:
        """Signal the program (if it still runs), wait for it and its readers."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            code = self.proc.wait(60.0)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            code = self.proc.wait()
        for t in self._threads:
            t.join()
        return code


# --- frames as candump -L writes them ------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """One frame of a candump -L line: ``123#11223344``, ``1A2B3C4D#`` (29 bits: 8 digits),
    ``123#R`` or ``123#R4`` (remote, with its DLC)."""

    cob_id: int
    extended: bool
    remote: bool
    data: bytes
    dlc: int
    time_s: float

    @property
    def key(self) -> tuple[int, bool, bool, bytes, int]:
        """What the wire carries (the time and the log's R/T flag left out)."""
        return (self.cob_id, self.extended, self.remote, self.data, self.dlc)

    @classmethod
    def parse(cls, line: str) -> Frame | None:
        parts = line.split()
        if len(parts) < 3 or not parts[0].startswith("("):
            return None
        ident, _, payload = parts[2].partition("#")
        remote = payload.startswith("R")
        data = b"" if remote else bytes.fromhex(payload)
        dlc = (int(payload[1:]) if payload[1:] else 0) if remote else len(data)
        return cls(int(ident, 16), len(ident) == 8, remote, data, dlc, float(parts[0][1:-1]))


def read_log(path: Path) -> list[Frame]:
    return [f for line in path.read_text().splitlines() if (f := Frame.parse(line))]


def parse_lines(lines: Sequence[str]) -> list[Frame]:
    return [f for line in lines if (f := Frame.parse(line))]


#: candump's socket receive buffer (bytes): a frame flood beside it on one CPU must not
#: overflow its queue (it then drops frames; ``-d`` would report them).
CANDUMP_RCVBUF = 8 * 1024 * 1024


#: Where the kernel keeps the receive buffer a socket gets unless it asks (bytes).
RMEM_DEFAULT = Path("/proc/sys/net/core/rmem_default")


@contextlib.contextmanager
def default_receive_buffer(size: int) -> Iterator[bool]:
    """Raise the kernel's default socket receive buffer to ``size`` while the block runs,
    for a can-utils program that cannot ask for one itself (``canbusload``): with the default
    (~240 frames) it loses frames of a lockstep burst while its one CPU runs the loop, and
    counts fewer than were sent. Yields False (changing nothing) where it is not writable."""
    try:
        old = RMEM_DEFAULT.read_text()
        RMEM_DEFAULT.write_text(str(max(size, int(old))))
    except OSError:
        yield False
        return
    try:
        yield True
    finally:
        RMEM_DEFAULT.write_text(old)


def candump(channel: str = "vcan0") -> Program:
    """``candump -L CHANNEL`` (every frame of the bus, as can-utils records it), ready: a
    probe frame sent after it started has come back through it."""
    recorder = Program(["candump", "-L", "-r", str(CANDUMP_RCVBUF), channel], "candump")
    probe = can.Bus(interface="socketcan", channel=channel)
    try:
        marker = bytes.fromhex("C0FFEE")
        sent = 0

        def seen(lines: list[str]) -> bool:
            if any((f := Frame.parse(x)) and f.data == marker for x in lines):
                return True
            nonlocal sent
            if sent < 1000:  # candump binds its socket a moment after it starts
                probe.send(can.Message(arbitration_id=0x7FF, data=marker, is_extended_id=False))
                sent += 1
            return False

        recorder.wait_for(seen, "the probe frame")
    finally:
        probe.shutdown()
    return recorder


def mark_end(recorder: Program, channel: str = "vcan0") -> list[Frame]:
    """Send an end marker and wait until candump recorded it: every frame the bus carried
    before is in its record then. Returns the record up to (without) the marker."""
    marker = bytes.fromhex("E0D0E0D0")
    bus = can.Bus(interface="socketcan", channel=channel)
    try:
        bus.send(can.Message(arbitration_id=0x7FF, data=marker, is_extended_id=False))
    finally:
        bus.shutdown()
    recorder.wait_for(
        lambda lines: any((f := Frame.parse(x)) and f.data == marker for x in lines),
        "the end marker",
    )
    frames = parse_lines(list(recorder.lines))
    end = next(i for i, f in enumerate(frames) if f.data == marker and f.cob_id == 0x7FF)
    return frames[:end]


def drive_process(
    axis_file: Path | None, clock: str, channel: str = "vcan0", extra: Sequence[str] = ()
) -> Program:
    """``python -m plant_sim drive`` on ``channel``, after its boot-up message; ``extra``:
    more options (``--fmu FMU --fmu-param ...``; then ``axis_file`` may be None)."""
    drive = Program(
        [
            sys.executable,
            "-m",
            "plant_sim",
            "drive",
            "--interface",
            "socketcan",
            "--channel",
            channel,
            *(["--axis", str(axis_file)] if axis_file is not None else []),
            "--clock",
            clock,
            *extra,
        ],
        "drive",
    )
    drive.wait_for(lambda lines: any("boot-up sent" in x for x in lines), "its boot-up")
    return drive


#: The lockstep bridge's wait for a TPDO (``--lockstep-wait``), s: the exchange is what these
#: tests check, not how fast a guest sharing two busy CPUs answers (the default 0.25 s is
#: a dead drive's bound; a starved guest once took longer and counted TPDOs missed).
LOCKSTEP_WAIT_S = 30.0


def bridge_argv(axis_file: Path, clock: str, tmp: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "bridge",
        "run",
        "--interface",
        "socketcan",
        "--channel",
        "vcan0",
        "--axis",
        str(axis_file),
        "--clock",
        clock,
        "--store",
        str(tmp / "bridge-store.json"),
        "--bus-log",
        str(tmp / "bus.log"),
        *(("--lockstep-wait", str(LOCKSTEP_WAIT_S)) if clock == "lockstep" else ()),
        *extra,
    ]


def find_window(record: Sequence[Frame], log: Sequence[Frame]) -> int | None:
    """Where ``log`` (frames, in order) is a contiguous part of ``record``, or None."""
    want = [f.key for f in log]
    keys = [f.key for f in record]
    n = len(want)
    for i in range(len(keys) - n + 1):
        if keys[i] == want[0] and keys[i : i + n] == want:
            return i
    return None
