"""``python -m bridge bench``: throughput in lockstep, latency in real time.

Lockstep: the paper's section X (regulated) through the full stack -- the bridge's loop,
python-can's virtual bus, the simulated drive with its PDO engine and physics in its own
thread -- once without recording and once with the trace file and the candump log; control
cycles per second of wall time and CPU time per cycle.

Real time: SYNC from the wall clock at the axis' position cycle (1 kHz for the paper's axis)
for ``seconds``, the axis moving back and forth; SYNC-to-set-point latency (SYNC sent to RPDO
sent, wall clock) median / p99 / max, how late SYNCs left against their schedule, skipped
SYNCs, cycles without a complete TPDO set, and CPU use of the process.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from plant_sim.axis import AxisConfig
from plant_sim.scenarios import SectionX
from regulator import RegulatorConfig

from .cycle import BridgeState
from .interpolator import Move
from .params import BridgeParams
from .sim import play_references, simulated_axis
from .timing import TimeMode


def _params(axis: AxisConfig) -> BridgeParams:
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    return BridgeParams.for_axis(axis, reg)


def lockstep_run(axis: AxisConfig, cycles: int, record: bool) -> dict[str, float]:
    """Section X (first ``cycles`` cycles; feed until 6 s) over the virtual bus, lockstep."""
    cycle_s = axis.control.position_cycle
    end_s = cycles * cycle_s
    scenario = SectionX(end_s=end_s, stop_s=min(SectionX.stop_s, end_s))
    refs = scenario.references(axis)
    with (
        tempfile.TemporaryDirectory() as tmp,
        simulated_axis(
            axis,
            _params(axis),
            trace_path=Path(tmp) / "trace.csv" if record else None,
            keep_trace=False,
            disturbance=refs.disturbance_nm if record else None,
            bus_log_path=Path(tmp) / "bus.log" if record else None,
        ) as sim,
    ):
        cpu0 = time.process_time()
        run = play_references(sim, refs)
        cpu = time.process_time() - cpu0
    return {
        "cycles": run.cycles,
        "wall_s": run.wall_s,
        "cycles_per_s": run.cycles / run.wall_s,
        "cpu_us_per_cycle": 1e6 * cpu / run.cycles,
        "missed_tpdos": run.counters.missed,
        "stopped": run.state is BridgeState.STOPPED,
    }


def realtime_run(axis: AxisConfig, seconds: float) -> dict[str, float]:
    """SYNC from the wall clock for ``seconds``; the axis moves ±20 mm (or rad) back and forth."""
    # counted, not acted on: a loaded host delays the simulated drive's thread now and then
    params = dataclasses.replace(_params(axis), pdo_loss_tolerance=255)
    cycles = round(seconds / params.cycle_s)
    with simulated_axis(
        axis, params, time_mode=TimeMode.REAL_TIME, keep_trace=False, keep_timing=True
    ) as sim:
        bridge = sim.bridge
        feed = params.feed
        move_s = 0.02 / feed + 0.1 + 0.1  # travel, acceleration ramps, dwell
        for i in range(math.ceil(seconds / move_s) + 2):
            bridge.controller.queue_move(
                Move(0.02 if i % 2 == 0 else 0.0, feed, accel=10 * feed, dwell_s=0.1)
            )
        wall0, cpu0 = time.perf_counter(), time.process_time()
        n = bridge.run(until=lambda b: b.cycle_index >= cycles)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        lat = bridge.latencies() * 1e6
        timing = bridge.timing
        assert timing is not None
        late = np.asarray(timing.sync_late_s) * 1e6
        counters = bridge.counters
        state = bridge.controller.state
    return {
        "seconds": wall,
        "cycles": n,
        "latency_us_median": float(np.median(lat)),
        "latency_us_p99": float(np.percentile(lat, 99)),
        "latency_us_max": float(np.max(lat)),
        "sync_late_us_median": float(np.median(late)),
        "sync_late_us_p99": float(np.percentile(late, 99)),
        "sync_late_us_max": float(np.max(late)),
        "skipped_syncs": timing.skipped_syncs,
        "missed_tpdo_cycles": counters.missed_cycles,
        "late_tpdos": counters.late,
        "cpu_percent_of_one_core": 100.0 * cpu / wall,
        "stopped": state is BridgeState.STOPPED,
    }


def run_bench(
    axis: AxisConfig,
    *,
    cycles: int,
    seconds: float | None,
    lockstep: bool = True,
    json_path: Path | None = None,
) -> dict[str, object]:
    results: dict[str, object] = {}
    if lockstep:
        for record in (False, True):
            key = "lockstep_recording" if record else "lockstep"
            r = lockstep_run(axis, cycles, record)
            results[key] = r
            print(
                f"{key}: {r['cycles']} cycles in {r['wall_s']:.3f} s = "
                f"{r['cycles_per_s']:.0f} cycles/s (paper's 6 s at 1 ms in "
                f"{6000 / r['cycles_per_s']:.2f} s), CPU {r['cpu_us_per_cycle']:.0f} µs/cycle, "
                f"missed TPDOs {r['missed_tpdos']}"
            )
    if seconds is not None:
        r = realtime_run(axis, seconds)
        results["realtime"] = r
        print(
            f"realtime {1 / axis.control.position_cycle:.0f} Hz for {r['seconds']:.1f} s: "
            f"SYNC-to-set-point latency median {r['latency_us_median']:.0f} µs, p99 "
            f"{r['latency_us_p99']:.0f} µs, max {r['latency_us_max']:.0f} µs; SYNC late "
            f"median {r['sync_late_us_median']:.0f} µs, p99 {r['sync_late_us_p99']:.0f} µs, "
            f"max {r['sync_late_us_max']:.0f} µs; skipped SYNCs {r['skipped_syncs']}, cycles "
            f"without all TPDOs {r['missed_tpdo_cycles']}; CPU {r['cpu_percent_of_one_core']:.0f} "
            "% of one core (bridge + simulated drive)"
        )
    if json_path is not None:
        json_path.write_text(json.dumps(results, indent=2) + "\n")
    return results
