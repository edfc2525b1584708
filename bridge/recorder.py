"""Recording of the loop: the trace file and a candump log of the bus traffic.

* :class:`TraceRecorder`: one row per cycle, the columns of ``docs/trace-file.md``
  (time, position_reference, speed_setpoint, motor_position, motor_speed, load_position,
  motor_torque, disturbance when known) plus beta, lambda and the loop's own values
  (:data:`EXTRA_COLUMNS`); recorded after the set point has gone out and written through
  :class:`virtual_bus.formats.trace.TraceWriter` in blocks of ``flush_rows`` rows (a killed
  recorder leaves whole rows and at most a torn last row, which the readers drop); optionally
  kept in memory for :meth:`TraceRecorder.trace`.
* :class:`BusLog`: every frame sent or received, in ``candump -L`` format through python-can's
  :class:`can.io.CanutilsLogWriter`: wall-clock epoch timestamps from the first frame on
  (the SDO start-up too, so can-utils' ``log2asc`` / ``canplayer`` and a second log of the
  same bus line up), the interface name of the bus (:func:`log_channel`, at most 15
  characters as a Linux interface name), appended in blocks that end before every
  ``flush_syncs``-th SYNC (:class:`virtual_bus.formats.records.RecordFile` with padding: no
  frame line crosses a 4096-byte boundary of the file, so a kill at any moment leaves whole
  lines that python-can and can-utils read).
* :class:`WireOrderBus`: on a bus that hands a process its own frames back (SocketCAN with
  ``receive_own_messages``), the log in the order the wire carried the frames, as ``candump
  -L`` records it from another process.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import can
import numpy as np

from virtual_bus import BusConfig, Interface
from virtual_bus.contract import SYNC_COB_ID
from virtual_bus.formats.records import RecordFile
from virtual_bus.formats.trace import RECORDED_COLUMNS, Trace, TraceWriter
from virtual_bus.own_frames import frame_key

from .cycle import CycleController

log = logging.getLogger("bridge")

BASE_COLUMNS = (
    *RECORDED_COLUMNS,
    "beta",
    "lambda",
)
#: Columns beyond the spec's: omega_s and omega_c (rad/s, motor), following error x_ref - x_l
#: and the motor-load difference since enable (load units), the bridge state (2104h value).
EXTRA_COLUMNS = ("omega_s", "omega_c", "following_error", "motor_load_difference", "state")
DEFAULT_FLUSH_ROWS = 100
#: Frames a bus log holds back at most (~0.6 MB): more between two of its SYNC blocks (a bus
#: without SYNC, a flood) are written at once.
MAX_PENDING_FRAMES = 16384
#: Linux IFNAMSIZ - 1: the longest interface name candump writes and log2asc reads back.
MAX_IFNAME_CHARS = 15


class TraceRecorder:
    """Per-cycle trace rows (see the module docstring).

    path: CSV file or None (memory only). keep: keep every row in memory for :meth:`trace`.
    disturbance: known disturbance per cycle (N·m at the motor, the spec's ``disturbance``
    column; rows beyond its end get 0), or None when the bridge cannot know it.
    flush_rows: rows per block, appended to the file as one block (TraceWriter); the bus log
    (:class:`BusLog`) writes blocks of as many SYNC cycles.
    """

    def __init__(
        self,
        path: str | Path | None,
        *,
        keep: bool = True,
        disturbance: np.ndarray | None = None,
        flush_rows: int = DEFAULT_FLUSH_ROWS,
    ) -> None:
        self.columns = (
            BASE_COLUMNS + (("disturbance",) if disturbance is not None else ()) + EXTRA_COLUMNS
        )
        self._dist = None if disturbance is None else np.asarray(disturbance, dtype=float)
        self._flush_rows = max(1, flush_rows)
        self._writer = (
            None if path is None else TraceWriter(path, self.columns, flush_every=self._flush_rows)
        )
        self._keep = keep
        self._block = np.empty((self._flush_rows, len(self.columns)))
        self._in_block = 0
        self._rows: list[np.ndarray] = []
        self._count = 0

    def record(self, c: CycleController) -> None:
        """Append the row of the cycle ``c`` just computed."""
        head = (
            c.now_s,
            c.position_reference,
            c.omega_r,
            c.motor_position_rad,
            c.motor_speed_rad_s,
            c.load_position,
            c.motor_torque_nm,
            c.vibration_level,
            c.switching_factor,
        )
        tail = (
            c.omega_s,
            c.omega_c,
            c.following_error,
            c.motor_load_difference,
            float(c.state.value),
        )
        if self._dist is not None:
            k = self._count
            values = (*head, float(self._dist[k]) if k < self._dist.size else 0.0, *tail)
        else:
            values = head + tail
        self._count += 1
        if self._writer is not None:
            self._writer.write_row(values)
        if self._keep:
            self._block[self._in_block] = values
        self._in_block += 1
        if self._in_block == self._flush_rows:
            self.flush()

    def flush(self) -> None:
        """Append the rows recorded since the last flush to the file (one block)."""
        if self._keep and self._in_block:
            self._rows.append(self._block[: self._in_block].copy())
        self._in_block = 0
        if self._writer is not None:
            self._writer.flush()

    @property
    def keeps_rows(self) -> bool:
        """Whether :meth:`trace` is available (``keep=True``)."""
        return self._keep

    @property
    def rows(self) -> int:
        return self._count

    def trace(self) -> Trace:
        """Everything recorded so far (needs ``keep=True``)."""
        if not self._keep:
            raise RuntimeError("this recorder keeps no rows in memory (keep=False)")
        self.flush()
        data = np.concatenate(self._rows) if self._rows else np.empty((0, len(self.columns)))
        return Trace({name: data[:, j].copy() for j, name in enumerate(self.columns)})

    def close(self) -> None:
        self.flush()
        if self._writer is not None:
            self._writer.close()


def log_channel(config: BusConfig) -> str:
    """The interface name a candump log of the bus ``config`` carries: the SocketCAN
    interface (vcan0, can0), the virtual bus's channel or the udp_multicast group, made a valid
    Linux interface name (at most 15 characters of ``A-Za-z0-9_.-``, as can-utils' ``log2asc``
    and ``canplayer`` read it): longer names are cut, other characters become ``_``."""
    if config.interface is Interface.SOCKETCAN or config.interface is Interface.AUTO:
        name = config.socketcan_channel
    elif config.interface is Interface.VIRTUAL:
        name = config.virtual_channel
    else:
        name = config.channel or str(config.interface)
    cleaned = re.sub(r"[^A-Za-z0-9_.\-]", "_", name)[:MAX_IFNAME_CHARS]
    if cleaned[0] in ".-":
        cleaned = "_" + cleaned[1:]
    return cleaned


class _Lines:
    """What python-can's writer writes to: the lines of the block being collected."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def write(self, text: str) -> int:
        self.lines.append(text)
        return len(text)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


class BusLog:
    """candump-format log (python-can CanutilsLogWriter) of frames sent and received.

    ``clock`` gives the timestamp written for each frame (default ``time.time``: epoch
    seconds, what candump writes), ``channel`` the interface name written with every frame
    (at most 15 characters, see :func:`log_channel`). The frames go to the file in blocks:
    before every ``flush_syncs``-th SYNC frame (the first SYNC's too: the start-up's frames),
    on :meth:`flush` and :meth:`close`, and when :data:`MAX_PENDING_FRAMES` wait. With the
    trace recorder's blocks of as many rows, a log and a trace a kill leaves agree
    (docs/bridge.md, "Recording"). A block that cannot be written (a full disk) is undone,
    logged as an error, and the log stops there (``failed``): logging a frame never raises
    into the loop that sends it. Thread-safe (start-up runs a receive thread).
    """

    def __init__(
        self,
        path: str | Path,
        clock: Callable[[], float] = time.time,
        channel: str = "can0",
        flush_syncs: int = DEFAULT_FLUSH_ROWS,
    ) -> None:
        if not 1 <= len(channel) <= MAX_IFNAME_CHARS or " " in channel:
            raise ValueError(
                f"log channel {channel!r}: allowed 1..{MAX_IFNAME_CHARS} characters without "
                "spaces (a Linux interface name, as candump writes it)"
            )
        self.channel = channel
        # the channel as CanutilsLogWriter writes it (a number n becomes "can<n>")
        self._line_channel = f"can{channel}" if channel.isdigit() else channel
        self._file = RecordFile(path, pad=True)
        sink = _Lines()
        self._lines = sink.lines
        self._writer = can.CanutilsLogWriter(sink, channel=channel)  # type: ignore[arg-type]
        self._now = clock
        self._lock = threading.Lock()
        self._flush_syncs = max(1, flush_syncs)
        self.frames = 0
        self.syncs = 0
        #: why the log stopped (a block that could not be written), None while it runs
        self.failed: OSError | None = None

    def log(self, msg: can.Message, received: bool) -> None:
        msg.is_rx = received
        msg.timestamp = timestamp = self._now()
        msg.channel = self.channel
        with self._lock:
            if self.failed is not None:
                return
            lines = self._lines
            if msg.arbitration_id == SYNC_COB_ID and not msg.is_extended_id:
                if self.syncs % self._flush_syncs == 0:
                    self._write_pending()
                self.syncs += 1
            writer = self._writer
            if msg.is_remote_frame and not (msg.is_error_frame or msg.is_fd):
                # candump writes a remote frame's DLC after the R ("602#R8", can-utils'
                # lib.c); python-can's writer leaves it out (its reader reads it back)
                if writer.last_timestamp is None:
                    writer.last_timestamp = timestamp
                timestamp = max(timestamp, writer.last_timestamp)
                width = 8 if msg.is_extended_id else 3
                lines.append(
                    f"({timestamp:f}) {self._line_channel} {msg.arbitration_id:0{width}X}#R"
                    f"{f'{msg.dlc:X}' if msg.dlc else ''}{' R' if received else ' T'}\n"
                )
            elif (
                msg.is_error_frame
                or msg.is_extended_id
                or msg.is_fd
                or writer.last_timestamp is None
            ):
                writer.on_message_received(msg)
            else:
                # CanutilsLogWriter.on_message_received's line for a standard data frame,
                # written here without its general case (tests/bridge/test_recorder.py
                # checks the file byte for byte against python-can's writer)
                if timestamp < writer.last_timestamp:
                    timestamp = writer.last_timestamp
                lines.append(
                    f"({timestamp:f}) {self._line_channel} {msg.arbitration_id:03X}#"
                    f"{msg.data.hex().upper()}{' R' if received else ' T'}\n"
                )
            self.frames += 1
            if len(lines) >= MAX_PENDING_FRAMES:
                self._write_pending()

    def _write_pending(self) -> None:
        if self._lines and self.failed is None:
            try:
                self._file.write_lines(self._lines)
            except OSError as exc:  # the file ends at the block before (RecordFile)
                self.failed = exc
                log.error("bus log %s failed, logging stops: %s", self._file.path, exc)
            self._lines.clear()

    def flush(self) -> None:
        """Write the frames logged so far."""
        with self._lock:
            self._write_pending()

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                try:
                    self._write_pending()
                finally:
                    self._file.close()


class WireOrderBus(can.BusABC):
    """The bridge's end of a bus whose frames are logged in the order the wire carried them.

    A log written when a frame is sent and when one is received has the order in which the
    bridge handled them: a drive's heartbeat that reached the bus just before the bridge's
    RPDO, but was read after it was sent, is logged after it, while ``candump`` on the same
    bus records it before. On SocketCAN the kernel hands a socket opened with
    ``receive_own_messages`` its own frames back in the bus's order among everyone else's,
    so this wrapper logs a sent frame when it comes back (the frames it sent and has not
    yet got back wait in a queue; a frame equal to the oldest of them is that one) and
    hands only the other nodes' frames on. ``inner``: the bus opened with
    ``receive_own_messages=True``; it stays the caller's to shut down, and ``log`` to close.
    """

    def __init__(self, inner: can.BusABC, log: BusLog) -> None:
        self._inner = inner
        self.log = log
        self._pending: deque[tuple[int, bool, bool, int, bytes]] = deque()
        self._lock = threading.Lock()
        self.channel_info = getattr(inner, "channel_info", "")
        super().__init__(channel=None)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        key = frame_key(msg)
        with self._lock:  # queued first: the echo may be read by another thread at once
            self._pending.append(key)
        try:
            self._inner.send(msg, timeout)
        except BaseException:
            with self._lock:  # never went out: no echo will come
                for i in range(len(self._pending) - 1, -1, -1):
                    if self._pending[i] == key:
                        del self._pending[i]
                        break
            raise

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        wait = timeout
        while True:
            msg = self._inner.recv(wait)
            if msg is None:
                return None, False
            with self._lock:
                own = bool(self._pending) and self._pending[0] == frame_key(msg)
                if own:
                    self._pending.popleft()
            self.log.log(msg, received=not own)
            if not own:
                return msg, False
            if deadline is not None:
                wait = max(0.0, deadline - time.monotonic())

    def shutdown(self) -> None:
        """Log the echoes still waiting (the last frames sent), then stop; a frame whose
        echo never came (the socket's receive buffer overflowed) is logged as sent, last."""
        while self._pending and self._recv_internal(0.0)[0] is not None:
            pass  # frames of other nodes read here are logged too: they were on the bus
        with self._lock:
            for key in self._pending:
                cob_id, extended, remote, dlc, data = key
                frame = can.Message(
                    arbitration_id=cob_id,
                    is_extended_id=extended,
                    is_remote_frame=remote,
                    dlc=dlc,
                    data=data,
                )
                self.log.log(frame, received=False)
            self._pending.clear()
        super().shutdown()
