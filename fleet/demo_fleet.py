"""A simulated fleet with a known truth: the monitor's test bed and its ``--demo``.

Every axis is the paper's axis (section IX, ``config/paper_axis.toml``) with its own k_v
(25..40 1/s for the vibrating axes, 20..32 for the others) and one of four conditions, recorded
on a routine test cycle every two weeks
over six months (the axis' closed loop of Fig. 1 simulated by the kernel):

* ``clean``: backlash 5 µm that does not change;
* ``growing``: backlash that grows from 20 µm by ``GROWTH_UM_PER_MONTH`` (wear);
* ``vibrating``: backlash 100 µm with the low viscous friction (5 N·m·s/m) under which the
  paper's limit cycle exists (docs/paper_reproduction.md): it shakes after the load pulse;
* ``corrupt``: a machine whose recorder writes broken files (cut short, garbage, time in ns).

The test cycle (25 s at 1 kHz): section X's run (feed 0.05 m/s with the 20 N·m load pulse
in the direction of motion from 2 to 4 s, then 5 s more at feed), back, forward and back
again (three reversals), each move on a trapezoid with 0.5 m/s². Recordings are trace files
(7 signals); every third recording of a clean or growing axis is written as a candump log
of the bridge's bus instead (:func:`write_candump`), so both readers are exercised.
``truth.json`` lists each axis' condition and true backlash per date.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plant_sim.physics.simulate import References, simulate
from virtual_bus.atomic import write_atomic
from virtual_bus.contract import (
    SYNC_COB_ID,
    rpdo_cob_id,
    sdo_rx_cob_id,
    sdo_tx_cob_id,
    tpdo_cob_id,
)
from virtual_bus.formats.axis import AxisConfig, load_axis
from virtual_bus.formats.trace import RECORDED_COLUMNS, Trace
from virtual_bus.shipped import PAPER_AXIS

CONDITIONS = ("clean", "growing", "vibrating", "corrupt")
GROWTH_UM_PER_MONTH = 10.0
TRACE_COLUMNS = RECORDED_COLUMNS
DURATION_S = 25.0
START = dt.datetime(2026, 5, 1, 7, 30)


@dataclass(frozen=True)
class FleetSpec:
    """Size of the demo fleet: machines × axes per machine, recordings per axis."""

    machines: int = 4
    axes_per_machine: int = 3
    recordings_per_axis: int = 12
    seed: int = 1


def condition_of(machine: int, axis: int, spec: FleetSpec) -> str:
    """Deterministic condition of axis ``axis`` of machine ``machine`` (0-based)."""
    if machine == spec.machines - 1 and axis == spec.axes_per_machine - 1:
        return "corrupt"
    return ("clean", "growing", "vibrating", "clean", "growing")[(machine + 2 * axis) % 5]


def test_cycle(
    cycle_s: float, feed: float = 0.05, accel: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """(position reference m, disturbance-on mask) of the 25 s test cycle, one per cycle.

    Section X's run first (feed 0.05 m/s, the load pulse from 2 to 4 s, 5 s more at feed),
    then back, forward and back again (three reversals), trapezoids with ``accel``.
    """
    n = round(DURATION_S / cycle_s)
    t = np.arange(n) * cycle_s
    speed = np.zeros(n)
    for start, direction, length in (
        (0.5, 1, 9.0),
        (10.5, -1, 4.0),
        (15.5, 1, 4.0),
        (20.5, -1, 4.0),
    ):
        in_move = (t >= start) & (t < start + length)
        tau = t[in_move] - start
        profile = np.minimum.reduce([accel * tau, np.full_like(tau, feed), accel * (length - tau)])
        speed[in_move] = direction * np.maximum(profile, 0.0)
    position = np.concatenate(([0.0], np.cumsum(speed[:-1]) * cycle_s))
    pulse = (t >= 2.0) & (t < 4.0)
    return position, pulse


def _axis_for(base: AxisConfig, condition: str, kv: float, backlash_m: float) -> AxisConfig:
    viscous = 5.0 if condition == "vibrating" else base.friction.viscous
    return base.with_values(
        {"control.kv": kv, "mechanics.backlash": backlash_m, "friction.viscous": viscous}
    )


def simulate_recording(axis: AxisConfig, rng: np.random.Generator) -> Trace:
    """One test-cycle recording of ``axis`` with encoder quantisation and scale noise."""
    cycle = axis.control.position_cycle
    position, pulse = test_cycle(cycle)
    dist = np.where(pulse, 20.0, 0.0)  # N·m at the motor, pushes towards +x (section X)
    trace = simulate(axis, References.from_position(position, cycle, dist))
    cols = {c: trace[c].copy() for c in TRACE_COLUMNS}
    inc = 2 * math.pi / (1 << 20)
    cols["motor_position"] = np.round(cols["motor_position"] / inc) * inc
    cols["load_position"] = (
        np.round((cols["load_position"] + rng.normal(0.0, 5e-8, cols["time"].size)) / 1e-9) * 1e-9
    )
    return Trace(cols)


def write_candump(
    trace: Trace, path: Path, start: dt.datetime, drive_id: int = 2, rated_torque_mnm: int = 20000
) -> None:
    """The recording as the bridge's bus would carry it (docs/canopen_layout.md), candump -l.

    Start-up SDO upload of 6076h (rated torque, mN·m), then per cycle SYNC, TPDO1 (6064h,
    60E4h:01 in nm), TPDO2 (6041h, 6077h in ‰, 606Ch) and RPDO1 (6040h, 60FFh), increments of
    2^20 per motor revolution; epoch time stamps from ``start``.
    """
    t0 = start.replace(tzinfo=dt.UTC).timestamp()
    inc_per_rad = (1 << 20) / (2 * math.pi)
    mpos = np.round(trace["motor_position"] * inc_per_rad).astype(np.int64)
    lpos = np.round(trace["load_position"] * 1e9).astype(np.int64)
    torque = np.round(trace["motor_torque"] / (rated_torque_mnm / 1e3) * 1000).astype(np.int64)
    mspd = np.round(trace["motor_speed"] * inc_per_rad).astype(np.int64)
    setp = np.round(trace["speed_setpoint"] * inc_per_rad).astype(np.int64)
    time = trace["time"]

    def le(value: int, size: int) -> str:
        return int(value).to_bytes(size, "little", signed=value < 0 or size in (2, 4)).hex().upper()

    lines = [
        f"({t0 - 0.01:.6f}) can0 {sdo_rx_cob_id(drive_id):03X}#4076600000000000",
        f"({t0 - 0.0099:.6f}) can0 {sdo_tx_cob_id(drive_id):03X}#43766000{le(rated_torque_mnm, 4)}",
    ]
    tpdo1, tpdo2 = tpdo_cob_id(1, drive_id), tpdo_cob_id(2, drive_id)
    rpdo1 = rpdo_cob_id(1, drive_id)
    for k in range(time.size):
        ts = t0 + time[k]
        lines.append(f"({ts:.6f}) can0 {SYNC_COB_ID:03X}#")
        lines.append(f"({ts + 0.00005:.6f}) can0 {tpdo1:03X}#{le(mpos[k], 4)}{le(lpos[k], 4)}")
        lines.append(
            f"({ts + 0.0001:.6f}) can0 {tpdo2:03X}#"
            f"{le(0x1237, 2)}{le(torque[k], 2)}{le(mspd[k], 4)}"
        )
        lines.append(f"({ts + 0.0002:.6f}) can0 {rpdo1:03X}#{le(0x000F, 2)}{le(setp[k], 4)}")
    write_atomic(path, "\n".join(lines) + "\n")


def _corrupt(kind: int, path: Path, trace: Trace) -> Path:
    if kind == 0:  # cut short mid-line: the recorder died
        path.write_text("time,motor_position,motor_torque\n0.0,0.1,0.2\n0.001,0.1")
    elif kind == 1:  # not a recording at all
        path = path.with_suffix(".log")
        path.write_bytes(b"\x00\x01garbage, not a candump log\n\xff\xfe")
    else:  # time written in ns
        ns = Trace({c: (trace[c] * 1e9 if c == "time" else trace[c]) for c in TRACE_COLUMNS})
        ns.to_csv(path)
    return path


def generate(
    out: Path, spec: FleetSpec = FleetSpec(), progress: Callable[[int, int], None] | None = None
) -> dict:
    """Write the fleet under ``out/MACHINE/AXIS/DATE.{csv,log}`` and ``out/truth.json``.

    Returns the truth: per axis id its condition, k_v, the true backlash per recording (m)
    and the recordings written.
    """
    out.mkdir(parents=True, exist_ok=True)
    base = load_axis(PAPER_AXIS)
    rng = np.random.default_rng(spec.seed)
    truth: dict[str, dict] = {}
    total = spec.machines * spec.axes_per_machine * spec.recordings_per_axis
    done = 0
    for m in range(spec.machines):
        for a in range(spec.axes_per_machine):
            machine, axis_name = f"M{m + 1:02d}", "XYZABC"[a]
            condition = condition_of(m, a, spec)
            # k_v where the condition is what the physics gives: with viscous 5 and 100 µm the
            # limit cycle exists from k_v ~ 25 up; with the paper's friction up to ~75 µm of
            # backlash it does not below k_v ~ 32 (measured with this test cycle)
            kv = float(
                rng.uniform(25.0, 40.0) if condition == "vibrating" else rng.uniform(20.0, 32.0)
            )
            folder = out / machine / axis_name
            folder.mkdir(parents=True, exist_ok=True)
            entry: dict = {"condition": condition, "kv": kv, "recordings": []}
            for r in range(spec.recordings_per_axis):
                date = START + dt.timedelta(days=14 * r)
                months = (date - START).days / 30.4375
                backlash = {
                    "clean": 5e-6,
                    "growing": 20e-6 + GROWTH_UM_PER_MONTH * 1e-6 * months,
                    "vibrating": 100e-6,
                    "corrupt": 10e-6,
                }[condition]
                axis = _axis_for(base, condition, kv, backlash)
                trace = simulate_recording(axis, rng)
                stem = date.strftime("%Y-%m-%dT%H-%M-%S")
                path = folder / f"{stem}.csv"
                if condition == "corrupt" and r % 2 == 1:
                    path = _corrupt(r // 2 % 3, path, trace)
                elif condition in ("clean", "growing") and r % 3 == 2:
                    path = path.with_suffix(".log")
                    write_candump(trace, path, date)
                else:
                    Trace({c: trace[c] for c in TRACE_COLUMNS}).to_csv(path)
                entry["recordings"].append(
                    {
                        "path": str(path.relative_to(out)),
                        "date": date.isoformat(),
                        "backlash_m": backlash,
                    }
                )
                done += 1
                if progress is not None:
                    progress(done, total)
            truth[f"{machine}/{axis_name}"] = entry
            axis_file = folder / "axis.toml"
            write_atomic(axis_file, _axis_toml(base, kv))
    write_atomic(out / "truth.json", json.dumps(truth, indent=1))
    write_atomic(out / "axes.toml", _axis_map(truth))
    return truth


def _axis_toml(base: AxisConfig, kv: float) -> str:
    from virtual_bus.formats.axis import dump_axis

    return dump_axis(
        base.with_values({"control.kv": kv}),
        header="demo fleet axis: the paper's axis with its own kv (nominal)",
    )


def _axis_map(truth: dict) -> str:
    lines = ["# axis map of the demo fleet: one [[axis]] per machine/axis", ""]
    for axis_id in truth:
        machine, axis = axis_id.split("/")
        lines += [
            "[[axis]]",
            f'machine = "{machine}"',
            f'axis = "{axis}"',
            f'axis_file = "{machine}/{axis}/axis.toml"',
            "",
        ]
    return "\n".join(lines)
