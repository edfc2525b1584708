"""Operating-system settings of a real-time loop's process: priority, CPU, memory, garbage
collector -- the same options for the bridge's loop (``python -m bridge run/bench``) and the
simulated drive's (``python -m plant_sim drive``), on their command lines as
:func:`add_realtime_options` and read back by :func:`realtime_options`.

All off by default (:class:`RealTimeOptions`). :func:`apply_realtime` asks the kernel for each
one that is on and raises :class:`RealTimeRefused` with one line naming the setting and the
reason when the OS does not allow it (nothing is half-applied silently: settings applied
before the refusal stay, and the message says which one failed).

* ``rt_priority``: ``SCHED_FIFO`` at that priority (1..99, ``os.sched_setscheduler``) for the
  calling process (the loop's thread is the main thread).
* ``cpu``: pin to that CPU (``os.sched_setaffinity``); with ``isolcpus=N`` on the kernel
  command line nothing else is scheduled there.
* ``lock_memory``: ``mlockall(MCL_CURRENT | MCL_FUTURE)`` through ctypes, so no page of the
  process is paged out (and, with MCL_FUTURE, new pages are locked as they are mapped).
* ``freeze_gc``: after start-up ``gc.freeze()`` moves everything allocated so far out of the
  collector's reach and ``gc.disable()`` stops automatic collections; the loop then collects
  the young generation itself between cycles, when there is time before the next SYNC
  (:class:`GcBetweenCycles`).
* ``busy_poll``: the loop polls the bus instead of blocking during the short window in which
  it expects a frame: the bridge while it waits for the TPDOs of a SYNC, the drive around the
  instant its next SYNC is due (no wake-up latency of a blocking wait, which is 50-60 µs on a
  small VM; the CPU stays busy during the window). Applied by the loops
  (``Bridge(busy_poll=...)``, ``plant_sim.drive.process.serve``).

``rt_priority`` and ``cpu`` act on the calling thread (and the threads it starts later):
apply them from the thread that runs the loop.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import gc
import os
from dataclasses import dataclass
from pathlib import Path

from cmdline.cli import integer

from .errors import RealTimeConfigError, RealTimeRefused

#: mlockall flags (linux/mman.h).
MCL_CURRENT = 1
MCL_FUTURE = 2
#: Range of SCHED_FIFO priorities on Linux.
FIFO_PRIORITY_RANGE = (1, 99)


@dataclass(frozen=True)
class RealTimeOptions:
    """Real-time settings of the loop's process; all off by default (module docstring)."""

    rt_priority: int | None = None
    cpu: int | None = None
    lock_memory: bool = False
    freeze_gc: bool = False
    busy_poll: bool = False

    def __post_init__(self) -> None:
        low, high = FIFO_PRIORITY_RANGE
        p = self.rt_priority
        if p is not None and (
            isinstance(p, bool) or not isinstance(p, int) or not low <= p <= high
        ):
            raise RealTimeConfigError(
                f"rt_priority = {p!r}: SCHED_FIFO priority must be {low}..{high}"
            )
        c = self.cpu
        if c is not None and (isinstance(c, bool) or not isinstance(c, int) or c < 0):
            raise RealTimeConfigError(f"cpu = {c!r}: must be a CPU number >= 0")

    @property
    def any(self) -> bool:
        return (
            self.rt_priority is not None
            or self.cpu is not None
            or self.lock_memory
            or self.freeze_gc
            or self.busy_poll
        )

    def describe(self) -> str:
        parts = []
        if self.rt_priority is not None:
            parts.append(f"SCHED_FIFO {self.rt_priority}")
        if self.cpu is not None:
            parts.append(f"CPU {self.cpu}")
        if self.lock_memory:
            parts.append("mlockall")
        if self.freeze_gc:
            parts.append("gc frozen, collected between cycles")
        if self.busy_poll:
            parts.append("bus polled where a frame is due")
        return ", ".join(parts) or "none (ordinary scheduling)"

    def argv(self) -> list[str]:
        """These options as the command-line arguments of :func:`add_realtime_options`
        (:func:`realtime_options` reads them back to equal options): for a process started
        with the same options."""
        flags = (
            ("--lock-memory", self.lock_memory),
            ("--freeze-gc", self.freeze_gc),
            ("--busy-poll", self.busy_poll),
        )
        numbers = (("--rt-priority", self.rt_priority), ("--cpu", self.cpu))
        return [a for name, n in numbers if n is not None for a in (name, str(n))] + [
            name for name, on in flags if on
        ]


def _set_fifo(priority: int) -> None:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        raise RealTimeRefused(
            f"--rt-priority {priority}: SCHED_FIFO refused by the OS ({exc.strerror}); needs "
            "root or CAP_SYS_NICE (or an rtprio limit in /etc/security/limits.conf)",
            setting="rt_priority",
            errno=exc.errno,
        ) from None


def _set_cpu(cpu: int) -> None:
    allowed = sorted(os.sched_getaffinity(0))
    if cpu not in allowed:
        raise RealTimeRefused(
            f"--cpu {cpu}: not a CPU this process may use; allowed {allowed}",
            setting="cpu",
        )
    try:
        os.sched_setaffinity(0, {cpu})
    except OSError as exc:
        raise RealTimeRefused(
            f"--cpu {cpu}: affinity refused by the OS ({exc.strerror})",
            setting="cpu",
            errno=exc.errno,
        ) from None


def _lock_memory() -> None:
    name = ctypes.util.find_library("c") or "libc.so.6"
    libc = ctypes.CDLL(name, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        errno = ctypes.get_errno()
        raise RealTimeRefused(
            f"--lock-memory: mlockall refused by the OS ({os.strerror(errno)}); needs root or "
            "CAP_IPC_LOCK, or a larger RLIMIT_MEMLOCK (ulimit -l)",
            setting="lock_memory",
            errno=errno,
        )


def apply_realtime(options: RealTimeOptions) -> list[str]:
    """Apply ``options`` to the calling process (see the module docstring); returns one line
    per setting applied. Raises :class:`RealTimeRefused` for the first one refused.

    ``freeze_gc`` is applied by :meth:`GcBetweenCycles.start` after start-up, not here."""
    done = []
    if options.cpu is not None:
        _set_cpu(options.cpu)
        done.append(f"pinned to CPU {options.cpu}")
    if options.lock_memory:
        _lock_memory()
        done.append("memory locked (mlockall MCL_CURRENT|MCL_FUTURE)")
    if options.rt_priority is not None:
        _set_fifo(options.rt_priority)
        done.append(f"SCHED_FIFO priority {options.rt_priority}")
    return done


class GcBetweenCycles:
    """The garbage collector under the loop's control (``freeze_gc``).

    :meth:`start` (after start-up): ``gc.freeze()`` and ``gc.disable()``. :meth:`collect`
    (between cycles, when the loop has time): a young-generation collection once
    ``threshold`` allocations have accumulated, the middle generation every ``ratio`` of them;
    the oldest generation never runs during the loop. :meth:`stop` re-enables the collector.
    """

    def __init__(self, threshold: int = 700, ratio: int = 10) -> None:
        self.threshold = threshold
        self.ratio = ratio
        self.collections = 0
        self._was_enabled = gc.isenabled()
        self._started = False

    def start(self) -> None:
        self._was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        self._started = True

    def due(self) -> bool:
        return self._started and gc.get_count()[0] >= self.threshold

    def collect(self) -> None:
        """One collection of the young (or every ``ratio``-th time the middle) generation."""
        self.collections += 1
        gc.collect(1 if self.collections % self.ratio == 0 else 0)

    def stop(self) -> None:
        if not self._started:
            return
        self._started = False
        gc.unfreeze()
        if self._was_enabled:
            gc.enable()


# --- command line ----------------------------------------------------------------------------
def add_realtime_options(parser: argparse.ArgumentParser) -> None:
    """--rt-priority, --cpu, --lock-memory, --freeze-gc, --busy-poll (all off by default;
    refused in one line, exit 1, where the OS does not allow them)."""
    parser.add_argument(
        "--rt-priority",
        type=_priority,
        metavar="N",
        help="run the loop under SCHED_FIFO at priority N (1..99; needs root/CAP_SYS_NICE)",
    )
    parser.add_argument("--cpu", type=cpu_number, metavar="N", help="pin the loop to CPU N")
    parser.add_argument(
        "--lock-memory", action="store_true", help="mlockall(MCL_CURRENT|MCL_FUTURE)"
    )
    parser.add_argument(
        "--freeze-gc",
        action="store_true",
        help="freeze the garbage collector after start-up; collect only between cycles",
    )
    parser.add_argument(
        "--busy-poll",
        action="store_true",
        help="poll the bus instead of blocking in the short window a frame is due (bridge: "
        "the TPDOs after its SYNC; drive: its next SYNC); that window's CPU time is spent",
    )


def _priority(text: str) -> int:
    return integer(text, 1, 99, "a SCHED_FIFO priority is 1..99")


def cpu_number(text: str) -> int:
    """A CPU number (argparse type)."""
    return integer(text, 0, None, "a CPU number is >= 0")


def check_cpu(cpu: int) -> None:
    """Refuse (RealTimeRefused, exit 1) a ``--cpu`` this process may not use."""
    if hasattr(os, "sched_getaffinity"):
        allowed = sorted(os.sched_getaffinity(0))
        if cpu not in allowed:
            raise RealTimeRefused(
                f"--cpu {cpu}: not a CPU this process may use; allowed {allowed}", setting="cpu"
            )


def realtime_options(args: argparse.Namespace) -> RealTimeOptions:
    """The real-time options of :func:`add_realtime_options` as :class:`RealTimeOptions`;
    a CPU this process may not use is refused here (RealTimeRefused, exit 1), before any
    work starts."""
    cpu = args.cpu
    if cpu is not None:
        check_cpu(cpu)
    return RealTimeOptions(
        rt_priority=args.rt_priority,
        cpu=cpu,
        lock_memory=args.lock_memory,
        freeze_gc=args.freeze_gc,
        busy_poll=args.busy_poll,
    )


# --- the host ---------------------------------------------------------------------------
def steal_s(stat_text: str) -> dict[str, float]:
    """Time the hypervisor ran something else while each CPU had work (the ``steal`` column
    of ``/proc/stat``, in USER_HZ ticks), s per CPU ("cpu0", ...). On a virtual machine a
    thread can lose the CPU for milliseconds this way, whatever its priority."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for line in stat_text.splitlines():
        fields = line.split()
        if fields and fields[0].startswith("cpu") and fields[0] != "cpu" and len(fields) > 8:
            out[fields[0]] = int(fields[8]) / tick
    return out


def host_steal_s() -> dict[str, float]:
    """:func:`steal_s` of this host now (empty where there is no /proc/stat)."""
    try:
        return steal_s(Path("/proc/stat").read_text())
    except OSError:
        return {}
