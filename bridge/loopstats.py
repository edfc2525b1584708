"""Timing of the loop, per cycle, in preallocated arrays (no list grows on the cycle path).

Per cycle (wall clock, s): how late the SYNC left against its slot on the schedule, SYNC sent
-> set point (RPDO) sent, and the bridge's own share of it (both TPDOs in -> RPDO sent); and
the CPU time of the loop's own work in the cycle (the thread's CPU time from the SYNC to the
RPDO sent, less the wait for the TPDOs, which busy polling spends on the CPU too).
Counts: SYNC slots skipped, cycles that overran (a slot after them was skipped) and the
longest run of them -- each overrun attributed to the loop's own work or to the host
(:meth:`Timing.overran`) -- frames the between-cycles service had to drop, errors caught on
the cycle path. :func:`summary` turns them into the figures of ``python -m hil bench``:
median / p99 / max, a histogram and the jitter of SYNC against its schedule.

Which floor binds: a skipped SYNC slot is the loop's own when its cycle -- the wait for the
drive's TPDOs (up to the end of their window), then its own work: the thread's CPU time for
sending the SYNC, recording, decoding, the controller and regulator, sending the RPDO, the
frames it served and the garbage it collected between cycles -- would
have ended too late for the slot even on a host that never took the CPU away. Otherwise the
slot was missed after the host kept the loop from running (a wake-up that came late, a task
or interrupt of higher priority, a hypervisor running something else on the virtual CPU).
The thread's CPU time of the work is its own also when the host took the CPU in between
(stolen time the guest cannot see counts as the thread's): it can only make a slot look the
loop's own, never the host's.
"""

from __future__ import annotations

import itertools

import numpy as np

#: Histogram bin edges of the latency figures, µs (the last bin is open).
HISTOGRAM_EDGES_US = (0, 50, 100, 150, 200, 300, 500, 1000, 2000, 5000)


class Timing:
    """Per-cycle timing of the loop (see the module docstring). ``capacity``: cycles kept
    (beyond it the arrays double: a rare allocation, never in a steady run whose length is
    known in advance)."""

    def __init__(self, capacity: int = 65536) -> None:
        capacity = max(16, capacity)
        # written now (np.full, not np.zeros), so no page is first touched in a cycle
        self._late = np.full(capacity, 0.0)
        self._latency = np.full(capacity, 0.0)
        self._compute = np.full(capacity, 0.0)
        self._work = np.full(capacity, 0.0)
        self.n = 0
        self.skipped_syncs = 0
        self.overruns = 0
        #: overruns (and the SYNC slots they skipped) the loop's own work caused, and those
        #: after the host kept the loop's thread off the CPU (module docstring)
        self.own_overruns = 0
        self.own_skipped = 0
        self.host_overruns = 0
        self.host_skipped = 0
        self.consecutive_overruns = 0
        self.max_consecutive_overruns = 0
        self.service_dropped = 0  # frames between cycles dropped: the service ring was full
        self.errors = 0  # exceptions caught on the cycle path (logged)
        #: cycle numbers (SYNCs sent before) of the first overruns, for diagnosis
        self.first_overruns: list[int] = []
        #: how the first overruns were attributed: wall time since the SYNC before, the
        #: wait for the TPDOs and the loop's own work in it, the missed slot's instant (µs)
        self.overrun_details: list[dict[str, object]] = []

    def record(
        self, sync_late_s: float, latency_s: float, compute_s: float, work_cpu_s: float = 0.0
    ) -> None:
        i = self.n
        if i == self._late.size:
            self._late = np.concatenate((self._late, np.zeros(i)))
            self._latency = np.concatenate((self._latency, np.zeros(i)))
            self._compute = np.concatenate((self._compute, np.zeros(i)))
            self._work = np.concatenate((self._work, np.zeros(i)))
        self._late[i] = sync_late_s
        self._latency[i] = latency_s
        self._compute[i] = compute_s
        self._work[i] = work_cpu_s
        self.n = i + 1

    def overran(self, skipped: int, by_host: bool | None = None) -> int:
        """Account the slots skipped before this SYNC (``by_host``: True after the host kept
        the loop off the CPU, False by the loop's own work, None not known); returns the
        overruns in a row."""
        if skipped:
            if len(self.first_overruns) < 16:
                self.first_overruns.append(self.n)
            if by_host:
                self.host_overruns += 1
                self.host_skipped += skipped
            elif by_host is not None:
                self.own_overruns += 1
                self.own_skipped += skipped
            self.skipped_syncs += skipped
            self.overruns += 1
            self.consecutive_overruns += 1
            if self.consecutive_overruns > self.max_consecutive_overruns:
                self.max_consecutive_overruns = self.consecutive_overruns
        else:
            self.consecutive_overruns = 0
        return self.consecutive_overruns

    @property
    def sync_late_s(self) -> np.ndarray:
        return self._late[: self.n]

    @property
    def latencies_s(self) -> np.ndarray:
        return self._latency[: self.n]

    @property
    def compute_s(self) -> np.ndarray:
        return self._compute[: self.n]

    @property
    def work_cpu_s(self) -> np.ndarray:
        return self._work[: self.n]


def _figures(values_s: np.ndarray, name: str) -> dict[str, float]:
    us = values_s * 1e6
    if us.size == 0:
        return {f"{name}_median": 0.0, f"{name}_p99": 0.0, f"{name}_max": 0.0}
    return {
        f"{name}_median": float(np.median(us)),
        f"{name}_p99": float(np.percentile(us, 99)),
        f"{name}_max": float(np.max(us)),
    }


def histogram(values_s: np.ndarray) -> dict[str, int]:
    """Counts per bin of :data:`HISTOGRAM_EDGES_US` ("0-50", ..., "5000+")."""
    us = values_s * 1e6
    edges = np.asarray((*HISTOGRAM_EDGES_US, np.inf))
    counts, _ = np.histogram(us, bins=edges)
    labels = [
        f"{int(lo)}-{int(hi)}" if np.isfinite(hi) else f"{int(lo)}+"
        for lo, hi in itertools.pairwise(edges)
    ]
    return {label: int(c) for label, c in zip(labels, counts, strict=True)}


def summary(timing: Timing, cycle_s: float) -> dict[str, object]:
    """Figures of a run: latency (SYNC -> RPDO), bridge compute (TPDOs in -> RPDO), SYNC
    lateness against the schedule and its jitter (standard deviation and peak-to-peak of the
    SYNC intervals minus the cycle), histograms, counts."""
    late = timing.sync_late_s
    out: dict[str, object] = {}
    out.update(_figures(timing.latencies_s, "latency_us"))
    out.update(_figures(timing.compute_s, "compute_us"))
    out.update(_figures(late, "sync_late_us"))
    work = timing.work_cpu_s
    out.update(_figures(work, "work_cpu_us"))
    out["work_cpu_fraction_of_period"] = float(np.median(work)) / cycle_s if work.size else 0.0
    out["sync_jitter_us_std"] = float(np.std(late) * 1e6) if late.size else 0.0
    out["sync_jitter_us_peak_to_peak"] = float(np.ptp(late) * 1e6) if late.size else 0.0
    out["latency_histogram_us"] = histogram(timing.latencies_s)
    out["sync_late_histogram_us"] = histogram(late)
    out["skipped_syncs"] = timing.skipped_syncs
    out["overruns"] = timing.overruns
    out["own_overruns"] = timing.own_overruns
    out["own_skipped_syncs"] = timing.own_skipped
    out["host_overruns"] = timing.host_overruns
    out["host_skipped_syncs"] = timing.host_skipped
    out["max_consecutive_overruns"] = timing.max_consecutive_overruns
    out["first_overrun_cycles"] = list(timing.first_overruns)
    out["first_overrun_details"] = list(timing.overrun_details)
    out["service_dropped"] = timing.service_dropped
    out["loop_errors"] = timing.errors
    out["cycle_us"] = cycle_s * 1e6
    return out
