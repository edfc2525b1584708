"""``python -m hil bench``: throughput in lockstep, latency in real time.

Lockstep: the paper's section X (regulated) through the full stack -- the bridge's loop,
python-can's virtual bus (:class:`virtual_bus.inprocess.InProcessBus`), the simulated drive
with its PDO engine and physics (receiving in the loop's thread) -- once without recording
and once with the trace file and the candump log; control cycles per second of wall time and
CPU time per cycle.

Real time (:mod:`hil.bench_realtime`): SYNC from the wall clock at ``rate_hz`` for
``seconds`` with the simulated drive in its own process (as root: udp_multicast in a private
network namespace) or in a thread; latency, SYNC jitter, histograms, skipped SYNCs, cycles
without a complete TPDO set, CPU time per cycle.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from bridge.cycle import BridgeState
from bridge.params import BridgeParams
from plant_sim.fmu.arguments import AxisSource
from plant_sim.paper.scenarios import SectionX
from regulator import RegulatorConfig
from virtual_bus.atomic import write_atomic
from virtual_bus.errors import RealTimeRefused
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.realtime import RealTimeOptions

from .bench_realtime import DrivePlacement, can_run_process_drive, realtime_run
from .harness import play_references, simulated_axis


def _params(axis: AxisConfig) -> BridgeParams:
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    return BridgeParams.for_axis(axis, reg)


def lockstep_run(
    axis: AxisConfig, cycles: int, record: bool, source: AxisSource | None = None
) -> dict[str, float]:
    """Section X (first ``cycles`` cycles; feed until 6 s) over the virtual bus, lockstep;
    ``source``: the drive's plant (default the compiled kernel of ``axis``; an FMU)."""
    cycle_s = axis.control.position_cycle
    end_s = cycles * cycle_s
    scenario = SectionX(end_s=end_s, stop_s=min(SectionX.stop_s, end_s))
    refs = scenario.references(axis)
    plant = None if source is None or source.model is None else source.plant()
    with (
        contextlib.closing(plant) if plant is not None else contextlib.nullcontext(),
        tempfile.TemporaryDirectory() as tmp,
        simulated_axis(
            axis,
            _params(axis),
            trace_path=Path(tmp) / "trace.csv" if record else None,
            keep_trace=False,
            disturbance=refs.disturbance_nm if record else None,
            bus_log_path=Path(tmp) / "bus.log" if record else None,
            plant=plant,
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


def _floors_line(r: dict[str, Any]) -> str:
    """The loop's cost against the period, its skipped SYNCs by cause, the host's floor
    measured beside it, and which floor bound."""
    period_us = 1e6 / r["rate_hz"]
    line = (
        f"floors: loop CPU {r['cpu_us_per_cycle']:.0f} µs/cycle = "
        f"{100 * r['cpu_fraction_of_period']:.0f} % of the {period_us:.0f} µs period (its work "
        f"alone, without spinning for the SYNC and waiting for the TPDOs: median "
        f"{r['work_cpu_us_median']:.0f} µs = {100 * r['work_cpu_fraction_of_period']:.1f} %, "
        f"p99 {r['work_cpu_us_p99']:.0f} µs; cycle core {r['cycle_core']}, frames: "
        f"{r['frames']}); skipped SYNCs {r['skipped_syncs']}: {r['own_skipped_syncs']} by the "
        f"loop's own work, {r['host_skipped_syncs']} after the host kept it off the CPU"
    )
    host = r.get("host_latency")
    if host is not None:
        line += (
            f"; the host in this run, just before the loop (cyclictest, SCHED_FIFO "
            f"{host['priority']}, CPU {host['cpu']}, {host['cycles']} wake-ups): "
            f"{host['over_slack']} at least {host['slack_us']} µs late (the loop's slack: "
            f"spin + allowed lateness), {host['late_cycles']} at least one cycle, p99 "
            f"{host['latency_us_p99']:.0f} µs, max {host['latency_us_max']} µs"
        )
    elif "host_latency_error" in r:
        line += f"; host in the same run: {r['host_latency_error']}"
    return line + f"; binding floor: {r['binding_floor']}"


#: Simulated seconds of section X the solve_ivp reference runs beside the lockstep figures.
REFERENCE_S = 1.0


def reference_run(axis: AxisConfig, seconds: float = REFERENCE_S) -> dict[str, float]:
    """The host's speed in the same run as the lockstep figures: ``seconds`` of section X
    through plant_sim's ``scipy.integrate.solve_ivp`` reference (the one ``plant_sim bench``
    times beside the kernel; SciPy's integrator, not this project's code). Lockstep cycles
    per second divided by its real-time factor changes with the project, not with the host."""
    from plant_sim.physics.reference import simulate_reference
    from plant_sim.physics.simulate import References

    refs = SectionX().references(axis)
    n = round(seconds / axis.control.position_cycle)
    part = References(refs.position[:n], refs.speed[:n], refs.disturbance_nm[:n])
    wall0 = time.perf_counter()
    simulate_reference(axis, part)
    wall = time.perf_counter() - wall0
    return {"simulated_s": seconds, "wall_s": wall, "realtime_factor": seconds / wall}


def _placement(drive: str) -> DrivePlacement:
    why = can_run_process_drive()
    if drive == "thread":
        return DrivePlacement.THREAD
    if why is None:
        print(
            "bench: the simulated drive runs as its own process (udp_multicast in a private "
            "network namespace, removed after the run)"
        )
        return DrivePlacement.PROCESS
    if drive == "process":
        raise RealTimeRefused(f"--drive process: {why}", setting="drive")
    print(
        f"bench: {why}; the simulated drive runs in this process instead (its physics and "
        "threads share the interpreter: the figures are not the bridge's alone)"
    )
    return DrivePlacement.THREAD


def _other_cpu(cpu: int | None) -> int | None:
    if cpu is None:
        return None
    others = sorted(set(os.sched_getaffinity(0)) - {cpu})
    return others[0] if others else None


def run_bench(
    axis: AxisConfig,
    *,
    cycles: int,
    seconds: float | None,
    lockstep: bool = True,
    json_path: Path | None = None,
    rate_hz: float | None = None,
    rt: RealTimeOptions | None = None,
    drive: str = "auto",
    drive_cpu: int | None = None,
    host_beside: bool = True,
    socketcan: str | None = None,
    fmu: AxisSource | None = None,
    scope: bool = False,
) -> dict[str, object]:
    """Every figure of ``hil bench`` (module docstring); ``fmu``: lockstep also with this FMU as
    the drive's plant, in the same run as the kernel's (``lockstep_fmu``)."""
    results: dict[str, object] = {}
    rt = rt or RealTimeOptions()
    if socketcan is not None:  # two processes on the interface: no namespace, no root
        placement = DrivePlacement.PROCESS
    else:
        placement = _placement(drive) if seconds is not None else DrivePlacement.THREAD
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
        if fmu is not None:
            r = lockstep_run(fmu.axis, cycles, False, fmu)
            results["lockstep_fmu"] = r
            what = fmu.fmu.describe() if fmu.fmu else fmu.name
            print(
                f"lockstep_fmu: {r['cycles']} cycles in {r['wall_s']:.3f} s = "
                f"{r['cycles_per_s']:.0f} cycles/s with the FMU {what} as the drive's "
                f"plant (the kernel's in the same run: "
                f"{results['lockstep']['cycles_per_s']:.0f}), CPU "  # type: ignore[index]
                f"{r['cpu_us_per_cycle']:.0f} µs/cycle, missed TPDOs {r['missed_tpdos']}"
            )
        ref = reference_run(axis)
        results["reference"] = ref
        for key in ("lockstep", "lockstep_recording"):
            lock = results[key]
            lock["cycles_per_s_per_reference_factor"] = (  # type: ignore[index]
                lock["cycles_per_s"] / ref["realtime_factor"]  # type: ignore[index]
            )
        print(
            f"reference in the same run: solve_ivp (scipy) {ref['simulated_s']:g} s of section "
            f"X at {ref['realtime_factor']:.2f}x real time; lockstep per unit of it: "
            f"{results['lockstep']['cycles_per_s_per_reference_factor']:.0f} and "  # type: ignore[index]
            f"{results['lockstep_recording']['cycles_per_s_per_reference_factor']:.0f} "  # type: ignore[index]
            "(host-independent: the project's speed)"
        )
    if seconds is not None:
        if drive_cpu is None and placement is DrivePlacement.PROCESS:
            drive_cpu = _other_cpu(rt.cpu)
        load = os.getloadavg()
        r = realtime_run(
            axis,
            seconds,
            rate_hz=rate_hz,
            rt=rt,
            placement=placement,
            drive_cpu=drive_cpu,
            host_beside=host_beside,
            socketcan=socketcan,
            scope=scope,
        )
        r["load_average_1_5_15"] = [round(x, 2) for x in load]
        results["realtime"] = r
        print(
            f"realtime {r['rate_hz']:.0f} Hz for {r['seconds']:.1f} s, drive: {r['drive']}, "
            f"options: {r['realtime_options']}, load average before {load[0]:.2f}: "
            f"SYNC-to-set-point latency median {r['latency_us_median']:.0f} µs, p99 "
            f"{r['latency_us_p99']:.0f} µs, max {r['latency_us_max']:.0f} µs (bridge's share "
            f"median {r['compute_us_median']:.0f} µs, p99 {r['compute_us_p99']:.0f} µs); SYNC "
            f"late median {r['sync_late_us_median']:.0f} µs, p99 {r['sync_late_us_p99']:.0f} "
            f"µs, max {r['sync_late_us_max']:.0f} µs; skipped SYNCs {r['skipped_syncs']} "
            f"({r['overruns']} overruns), cycles without all TPDOs {r['missed_tpdo_cycles']}; "
            f"loop CPU {r['cpu_us_per_cycle']:.0f} µs/cycle"
            + (
                f", drive process CPU {r['drive_cpu_us_per_cycle']:.0f} µs/cycle"
                if "drive_cpu_us_per_cycle" in r
                else ""
            )
        )
        print(f"latency histogram (µs): {r['latency_histogram_us']}")
        print(_floors_line(r))
        if "host_gaps_over_50us" in r:
            print(
                f"host alone (a clock-reading thread, same options, {r['host_gaps_over_50us']} "
                f"gaps > 50 µs in 2 s before the run, longest {r['host_gap_us_max']:.0f} µs)"
            )
        print(f"CPU time the hypervisor stole during the run (ms): {r['host_steal_ms']}")
    if json_path is not None:
        write_atomic(json_path, json.dumps(results, indent=2) + "\n")
    return results
