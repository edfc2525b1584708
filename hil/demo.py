"""``python -m hil demo --out DIR``: the paper's section X over the bus.

The same runs as ``python -m plant_sim paper`` (ordinary control, Fig. 8, and with the
regulator, Fig. 9; if the axis as given shows no limit cycle, again with the guideway friction
of ``plant_sim.paper.outputs.LIMIT_CYCLE_VISCOUS``), but each run is the bridge closing the
loop over CANopen with the simulated drive (default: python-can's virtual bus, lockstep).
Summary and figures come from :func:`plant_sim.paper.outputs.write_paper_outputs`, so they are the
paper command's. In addition: the live trace of each run as the recorder wrote it (the same
``{run}.csv`` file names), the candump log of each run's bus traffic (``bus_{run}.log``) and,
in summary.json under ``"bridge"``, the loop's counters and the deviation from the offline
simulation with the same one-cycle PDO delay.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from bridge.cycle import BridgeState
from bridge.errors import BridgeError
from bridge.params import BridgeParams
from plant_sim.paper.outputs import (
    files_line,
    limit_cycle_variant,
    summarize,
    write_as_given,
    write_paper_outputs,
)
from plant_sim.paper.scenarios import SectionX
from plant_sim.physics.model import AxisPlant, KernelOptions
from plant_sim.physics.simulate import simulate
from regulator import RegulatorConfig
from virtual_bus import Interface
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace
from virtual_bus.progress import Progress, silent

from .harness import run_references

RUNS = (("ordinary", False), ("regulated", True))


def compare_with_offline(
    trace: Trace, axis: AxisConfig, scenario: SectionX, regulator: RegulatorConfig
) -> dict[str, float]:
    """Largest differences between a bus run and ``simulate`` with the one-cycle PDO delay:
    following error (load units), beta (rad/s), lambda."""
    offline = simulate(
        axis, scenario.references(axis), regulator, KernelOptions(setpoint_delay_cycles=1)
    )
    e_bus = trace["position_reference"] - trace["load_position"]
    e_off = offline["position_reference"] - offline["load_position"]
    return {
        "max_following_error_difference": float(np.max(np.abs(e_bus - e_off))),
        "max_beta_difference_rad_s": float(np.max(np.abs(trace["beta"] - offline["beta"]))),
        "max_lambda_difference": float(np.max(np.abs(trace["lambda"] - offline["lambda"]))),
        "max_following_error": float(np.max(np.abs(e_off))),
        "max_beta_rad_s": float(np.max(offline["beta"])),
    }


def bus_runs(
    axis: AxisConfig,
    out_dir: Path,
    scenario: SectionX,
    interface: Interface,
    prefix: str = "",
    progress: Progress | None = None,
    label: str = "",
) -> tuple[dict[str, Trace], dict[str, object]]:
    """Both runs of section X over the bus; traces and per-run bridge figures."""
    progress = progress or silent()
    traces: dict[str, Trace] = {}
    info: dict[str, object] = {}
    refs = scenario.references(axis)
    for name, enabled in RUNS:
        progress.stage(
            f"{label}{name} run over the {interface.value} bus: {refs.position.size} cycles in "
            "lockstep, then the offline simulation to compare"
        )
        reg = RegulatorConfig(
            kv=axis.control.kv, cycle_s=axis.control.position_cycle, enabled=enabled
        )
        run = run_references(
            axis,
            refs,
            BridgeParams.for_axis(axis, reg),
            interface=interface,
            trace_path=out_dir / f"{prefix}{name}.csv",
            bus_log_path=out_dir / f"{prefix}bus_{name}.log",
        )
        if run.state is not BridgeState.RUNNING:
            raise BridgeError(
                f"run {prefix}{name}: the bridge stopped the axis: {run.stop_message}"
            )
        traces[name] = run.trace
        info[name] = {
            "cycles": run.cycles,
            "wall_s": run.wall_s,
            "cycles_per_s": run.cycles / run.wall_s,
            "pdo_counters": asdict(run.counters),
            "offline_comparison": compare_with_offline(run.trace, axis, scenario, reg),
        }
    return traces, info


def run_demo(
    out_dir: Path,
    axis: AxisConfig,
    axis_name: str,
    interface: Interface = Interface.VIRTUAL,
    progress: Progress | None = None,
) -> dict[str, object]:
    """Everything ``python -m hil demo`` does; returns summary.json's content (its
    "files" lists every file written). An axis the bridge or the physics cannot run is
    refused before ``out_dir`` is made."""
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    BridgeParams.for_axis(axis, reg)  # the bridge's scaling limits
    AxisPlant(axis)  # the physics' limits (substeps)
    progress = progress or silent()
    out_dir.mkdir(parents=True, exist_ok=True)
    scenario = SectionX()
    runs, info = bus_runs(
        axis, out_dir, scenario, interface, progress=progress, label="axis as given: "
    )
    extra: dict[str, object] = {
        "axis_file": axis_name,
        "bridge": {"bus": interface.value, "time_mode": "lockstep", "runs": info},
    }
    published = {name: summarize(trace, axis, scenario) for name, trace in runs.items()}
    decided = limit_cycle_variant(axis, published, axis_name, out_dir)
    if decided is not None:
        # as python -m plant_sim paper does: the axis as given damps the limit cycle out
        logs = []
        for name in runs:
            (out_dir / f"{name}.csv").unlink()
            (out_dir / f"bus_{name}.log").rename(out_dir / f"as_given_bus_{name}.log")
            logs.append(f"as_given_bus_{name}.log")
        as_given_files, as_given_note = write_as_given(out_dir, runs)
        axis, more = decided
        extra.update(more)
        extra["as_given_files"] = as_given_note
        extra["files_written"] = [*more.get("files_written", []), *as_given_files, *logs]  # type: ignore[misc]
        progress.stage("the axis as given shows no limit cycle: both runs again, lower friction")
        runs, variant_info = bus_runs(
            axis,
            out_dir,
            scenario,
            interface,
            progress=progress,
            label=f"friction.viscous = {axis.friction.viscous:g} N m s/m: ",
        )
        extra["bridge"] = {
            "bus": interface.value,
            "time_mode": "lockstep",
            "runs": variant_info,
            "as_given_runs": info,
        }
    extra["files_written"] = [
        *extra.get("files_written", []),  # type: ignore[misc]
        *(f"bus_{name}.log" for name in runs),
    ]
    progress.stage("figures and summary")
    return write_paper_outputs(out_dir, runs, axis, scenario, extra)


def print_summary(summary: dict[str, object], out_dir: Path) -> None:
    keys = ("band_hz", "runs", "p2p_reduction")
    print(json.dumps({k: summary[k] for k in keys if k in summary}, indent=2))
    bridge = summary.get("bridge", {})
    runs = bridge.get("runs", {}) if isinstance(bridge, dict) else {}
    for name, run in runs.items():
        cmp = run["offline_comparison"]
        print(
            f"{name}: {run['cycles']} cycles at {run['cycles_per_s']:.0f}/s, "
            f"missed TPDOs {run['pdo_counters']['missed']}; vs offline: following error "
            f"{cmp['max_following_error_difference']:.3g}, beta "
            f"{cmp['max_beta_difference_rad_s']:.3g} rad/s, lambda "
            f"{cmp['max_lambda_difference']:.3g}"
        )
    if "finding" in summary:
        print(f"note: {summary['finding']}")
    print(files_line(out_dir, summary))
