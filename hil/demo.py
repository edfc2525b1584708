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
from collections.abc import Callable, Mapping
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from bridge.cycle import BridgeState
from bridge.errors import BridgeError
from bridge.node import Bridge
from bridge.params import BridgeParams
from cmdline.progress import Progress, silent
from cmdline.quantity import percent, quantity, resolved
from plant_sim.fmu.arguments import AxisSource
from plant_sim.paper.outputs import (
    SETTLE_AFTER_DISTURBANCE_S as SETTLE_S,
)
from plant_sim.paper.outputs import (
    RunSummary,
    files_line,
    limit_cycle_variant,
    summarize,
    write_as_given,
    write_paper_outputs,
)
from plant_sim.paper.scenarios import SectionX
from plant_sim.physics.model import AxisPlant, KernelOptions
from plant_sim.physics.simulate import References, simulate
from plant_sim.physics.warm import warm_up
from regulator import RegulatorConfig
from virtual_bus import Interface
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from .harness import run_references
from .loop import run_loop

RUNS = (("ordinary", False), ("regulated", True))

#: Feeds (load units/s) an FMU axis is tried at, in this order, when the paper's feed shows no
#: limit cycle: the FMU's friction cannot be lowered as the kernel's is (``limit_cycle_variant``),
#: but at a lower feed the friction force that holds the gap closed after the disturbance is
#: lower too (docs/fmu.md, "The demo on an FMU").
FMU_FEEDS = (0.02, 0.01, 0.005)


def offline_run(
    source: AxisSource, axis: AxisConfig, refs: References, regulator: RegulatorConfig
) -> Trace:
    """The same run without a bus: the kernel's closed loop with the one-cycle PDO delay, or
    the bridge's loop (:func:`hil.loop.run_loop`) around a fresh instance of the FMU."""
    return offline_stopped(source, axis, refs, regulator)[0]


def offline_stopped(
    source: AxisSource, axis: AxisConfig, refs: References, regulator: RegulatorConfig
) -> tuple[Trace, str | None]:
    """:func:`offline_run` and why the bridge's supervision stopped the FMU's axis (its
    2008h / 2009h / 2014h, as :func:`hil.loop.run_loop` words it; None: it ran to the end;
    the kernel's loop has no limits). After a stop the set point is 0 and the axis holds
    where it stopped, so a figure of the rest of the run says nothing about the law."""
    if source.model is None:
        return simulate(axis, refs, regulator, KernelOptions(setpoint_delay_cycles=1)), None
    with source.plant(float(refs.position[0]), "offline") as plant:
        rec = run_loop(
            plant,
            refs.position,
            refs.speed,
            axis.transmission_ratio,
            regulator,
            axis.control.velocity_feedforward or 0.0,
            refs.disturbance_nm,
            BridgeParams.for_axis(axis, regulator),
        )
    trace = Trace(
        {
            "time": np.arange(rec.cycles) * axis.control.position_cycle,
            "position_reference": rec.position_reference,
            "load_position": rec.load_position,
            "beta": rec.beta,
            "lambda": rec.switching_factor,
        }
    )
    return trace, rec.stop_reason


def compare_with_offline(trace: Trace, offline: Trace) -> dict[str, float]:
    """Largest differences between a bus run and the same run offline
    (:func:`offline_run`): following error (load units), beta (rad/s), lambda."""
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
    source: AxisSource,
    axis: AxisConfig,
    out_dir: Path,
    scenario: SectionX,
    interface: Interface,
    prefix: str = "",
    progress: Progress | None = None,
    label: str = "",
    watch: Callable[[Bridge], None] | None = None,
) -> tuple[dict[str, Trace], dict[str, object]]:
    """Both runs of section X over the bus; traces and per-run bridge figures. ``watch``:
    called with each run's bridge (the live scope)."""
    progress = progress or silent()
    traces: dict[str, Trace] = {}
    info: dict[str, object] = {}
    refs = scenario.references(axis)
    for name, enabled in RUNS:
        progress.stage(
            f"{label}{name} run over the {interface.value} bus: {refs.position.size} cycles in "
            "lockstep, then the offline run to compare"
        )
        reg = RegulatorConfig(
            kv=axis.control.kv, cycle_s=axis.control.position_cycle, enabled=enabled
        )
        plant = source.plant(float(refs.position[0]), f"drive-{name}")
        try:
            run = run_references(
                axis,
                refs,
                BridgeParams.for_axis(axis, reg),
                interface=interface,
                trace_path=out_dir / f"{prefix}{name}.csv",
                bus_log_path=out_dir / f"{prefix}bus_{name}.log",
                plant=plant,
                watch=watch,
            )
        finally:
            plant.close()
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
            "offline_comparison": compare_with_offline(
                run.trace, offline_run(source, axis, refs, reg)
            ),
        }
    return traces, info


#: An FMU's ordinary run limit-cycles when the last SUSTAINED_S before the interpolator stops
#: still vibrate in the eq. 13 band: a vibration that the friction damps out within a second
#: after the disturbance is a transient, not the limit cycle of Fig. 8.
SUSTAINED_S = 1.0


def late_verdict(trace: Trace, axis: AxisConfig, scenario: SectionX) -> RunSummary:
    """The section X verdict of :func:`summarize` on the last :data:`SUSTAINED_S` of the
    feed only."""
    late = replace(scenario, disturbance_end_s=scenario.stop_s - SUSTAINED_S - SETTLE_S)
    return summarize(trace, axis, late)


def sustained(trace: Trace, axis: AxisConfig, scenario: SectionX) -> bool:
    """The run's following error still vibrates in the eq. 13 band over the last
    :data:`SUSTAINED_S` of the feed (:func:`late_verdict`)."""
    return late_verdict(trace, axis, scenario).in_band


def fmu_feed_variant(
    source: AxisSource, axis: AxisConfig, scenario: SectionX, published: dict[str, RunSummary]
) -> tuple[SectionX, dict[str, object]] | None:
    """The FMU's counterpart of :func:`limit_cycle_variant`: where the ordinary run at the
    scenario's feed shows no sustained limit cycle, the first of :data:`FMU_FEEDS` at which the
    offline ordinary run does (None: keep the feed; also when none does). Sustained
    (:func:`sustained`), not the transient that :func:`summarize`'s window may still catch."""
    ordinary = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    ordinary = replace(ordinary, enabled=False)
    if sustained(offline_run(source, axis, scenario.references(axis), ordinary), axis, scenario):
        return None
    for feed in FMU_FEEDS:
        trial = replace(scenario, feed=feed)
        if not sustained(offline_run(source, axis, trial.references(axis), ordinary), axis, trial):
            continue
        return trial, {
            "as_given": {name: asdict(s) for name, s in published.items()},
            "finding": (
                f"At the paper's feed of {scenario.feed * 1e3:g} mm/s the FMU's friction holds "
                "the backlash gap closed after the disturbance: no sustained limit cycle under "
                f"ordinary control. Figures, traces and 'runs' are at a feed of {feed * 1e3:g} "
                "mm/s, the first of "
                + ", ".join(f"{f * 1e3:g}" for f in FMU_FEEDS)
                + " mm/s at which the offline ordinary run shows one (docs/fmu.md)."
            ),
            "figures_axis_changes": {"section X feed [m/s]": feed},
        }
    return None


def run_demo(
    out_dir: Path,
    axis: AxisConfig,
    axis_name: str,
    interface: Interface = Interface.VIRTUAL,
    progress: Progress | None = None,
    source: AxisSource | None = None,
    watch: Callable[[Bridge], None] | None = None,
) -> dict[str, object]:
    """Everything ``python -m hil demo`` does; returns summary.json's content (its
    "files" lists every file written). ``source``: the plant (default: the compiled kernel
    of ``axis``; an FMU). An axis the bridge or the physics cannot run is refused before
    ``out_dir`` is made. ``watch``: called with each bus run's bridge (``--scope``)."""
    source = source or AxisSource(axis, axis_name)
    reg = RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    BridgeParams.for_axis(axis, reg)  # the bridge's scaling limits
    if source.model is None:
        AxisPlant(axis)  # the physics' limits (substeps)
    progress = progress or silent()
    out_dir.mkdir(parents=True, exist_ok=True)
    progress.stage(
        "loading the compiled simulator and bridge cycle (numba): a first run compiles them, "
        "about a minute on two busy cores"
    )
    progress.stage(warm_up(axis, kernel=source.model is None).sentence())
    scenario = SectionX()
    runs, info = bus_runs(
        source,
        axis,
        out_dir,
        scenario,
        interface,
        progress=progress,
        label="axis as given: ",
        watch=watch,
    )
    extra: dict[str, object] = {
        "axis_file": axis_name,
        "bridge": {"bus": interface.value, "time_mode": "lockstep", "runs": info},
    }
    if source.fmu is not None:
        extra["plant"] = {
            "fmu": str(source.fmu.path),
            "parameters": dict(source.fmu.parameters),
            "mapping": source.fmu.mapping.describe(),
        }
    published = {name: summarize(trace, axis, scenario) for name, trace in runs.items()}
    more: dict[str, object] | None = None
    if source.model is None:  # the kernel: the same axis with lower friction
        if (lower := limit_cycle_variant(axis, published, axis_name, out_dir)) is not None:
            axis, more = lower
            source = AxisSource(axis, axis_name)
            label = f"friction.viscous = {axis.friction.viscous:g} N m s/m: "
            why = "lower friction"
    elif (slower := fmu_feed_variant(source, axis, scenario, published)) is not None:
        scenario, more = slower  # an FMU: the same axis at a lower feed
        label = f"feed {scenario.feed * 1e3:g} mm/s: "
        why = "lower feed"
    if more is not None:
        # as python -m plant_sim paper does: the axis as given damps the limit cycle out
        logs = []
        for name in runs:
            (out_dir / f"{name}.csv").unlink()
            (out_dir / f"bus_{name}.log").rename(out_dir / f"as_given_bus_{name}.log")
            logs.append(f"as_given_bus_{name}.log")
        as_given_files, as_given_note = write_as_given(out_dir, runs)
        extra.update(more)
        extra["as_given_files"] = as_given_note
        extra["files_written"] = [*more.get("files_written", []), *as_given_files, *logs]  # type: ignore[misc]
        progress.stage(f"the axis as given shows no limit cycle: both runs again, {why}")
        runs, variant_info = bus_runs(
            source, axis, out_dir, scenario, interface, progress=progress, label=label, watch=watch
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


def summary_lines(summary: Mapping[str, Any]) -> list[str]:
    """The demo's result as an engineer reads it: what vibrated, at what frequency, how far,
    in µm or mm (summary.json holds the same in SI units)."""
    unit = str(summary.get("load_unit", "m"))
    band = summary["band_hz"]
    p0, p1 = summary["p2p_window_s"]
    f0, f1 = summary.get("frequency_window_s", (p0, p1))
    bridge = summary.get("bridge", {})
    lines = [
        f"section X over the {bridge.get('bus', '?')} bus, {bridge.get('time_mode', '?')}: "
        f"eq. 13 band {band[0]:g}–{band[1]:g} Hz (k_v = {summary['kv_per_s']:g} 1/s); "
        f"peak to peak over {p0:g}–{p1:g} s, frequency over {f0:g}–{f1:g} s"
    ]
    names = {"ordinary": "ordinary control (Fig. 8)", "regulated": "with the regulator (Fig. 9)"}
    runs = summary["runs"]
    for name, run in runs.items():
        f = run["dominant_frequency_hz"]
        where = "in the band" if run["in_band"] else "outside the band"
        amplitude = quantity(run["vibration_amplitude"], unit)
        vib = (
            f"vibrates at {f:.3g} Hz ({where}), amplitude {amplitude}"
            if f is not None
            else f"no vibration (amplitude {amplitude})"
        )
        p2p = quantity(run["p2p_following_error"], unit)
        if name == "regulated" and summary.get("p2p_reduction") is not None:
            p2p += f" ({percent(-100 * summary['p2p_reduction'])})"
        lines.append(
            f"  {names.get(name, name)}: {vib}; following error {p2p} peak to peak; "
            f"standstill error {resolved(run['final_standstill_error'], unit)}; "
            f"β max {run['max_beta_rad_s']:.3g} rad/s, λ min {run['min_lambda']:.3g}"
        )
    for name, run in (bridge.get("runs") or {}).items():
        cmp = run["offline_comparison"]
        lines.append(
            f"  {name} over the bus: {run['cycles']} cycles at {run['cycles_per_s']:.0f} "
            f"cycles/s, missed TPDOs {run['pdo_counters']['missed']}; against the offline run: "
            f"following error within {quantity(cmp['max_following_error_difference'], unit)}, "
            f"β within {cmp['max_beta_difference_rad_s']:.3g} rad/s, λ within "
            f"{cmp['max_lambda_difference']:.3g}"
        )
    return lines


def print_summary(summary: dict[str, object], out_dir: Path, as_json: bool = False) -> None:
    """The human summary (:func:`summary_lines`) on stdout, or with ``as_json`` summary.json's
    content; then the note and the line naming the files."""
    if as_json:
        print(json.dumps(summary, indent=2))
        return
    for line in summary_lines(summary):
        print(line)
    if "finding" in summary:
        print(f"note: {summary['finding']}")
    print(files_line(out_dir, summary))
