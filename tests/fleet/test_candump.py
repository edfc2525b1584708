"""Candump logs written by the bridge itself, decoded by the fleet monitor (candump.py).

The independent part: the log is the bridge's own bus log of a real start-up and loop (the
PDO parameters written over SDO, then SYNC/TPDO/RPDO traffic), and the decoded positions are
compared with what the simulated drive's physics says at the end.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from bridge.cycle import BridgeState
from bridge.interpolator import Move
from bridge.node import BridgeConfig
from bridge.params import BridgeParams
from fleet.candump import CandumpLayout, layout_for, read_candump_chunks
from fleet.errors import TimeBaseWarning
from hil.harness import simulated_axis
from regulator import RegulatorConfig
from tests.paths import ROOT
from virtual_bus import Interface
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.drive_profile import LoadSource, load_profile

AXIS = load_axis(ROOT / "config" / "paper_axis.toml")
DRIVES = ROOT / "config" / "drives"


def _params() -> BridgeParams:
    reg = RegulatorConfig(kv=AXIS.control.kv, cycle_s=AXIS.control.position_cycle)
    return BridgeParams.for_axis(AXIS, reg)


def _move_and_log(tmp_path: Path, config: BridgeConfig) -> tuple[Path, float, int]:
    log = tmp_path / "bus.log"
    with simulated_axis(
        AXIS, _params(), interface=Interface.VIRTUAL, bridge_config=config, bus_log_path=log
    ) as sim:
        c = sim.bridge.controller
        sim.bridge.run(until=lambda b: b.controller.state is not BridgeState.ENABLING)
        c.queue_move(Move(c.load_position + 0.004, 0.02))
        sim.bridge.run(cycles=600)
        assert c.state is BridgeState.RUNNING, c.stop_message
        final_motor_rad = sim.drive.plant.motor_position_rad
        syncs = sim.bridge.cycle_index
    return log, final_motor_rad, syncs


def test_log_of_an_adapted_layout_is_decoded_by_its_own_pdo_mapping(tmp_path: Path) -> None:
    """TPDO3/TPDO4 with motor feedback only (a drive without a load measuring system): the
    mapping comes from the start-up's SDO writes in the log; the contract's TPDO1/TPDO2
    would decode nothing."""
    profile = dataclasses.replace(
        load_profile(DRIVES / "simdrive.toml"), load_source=LoadSource.MOTOR, tpdos=(3, 4)
    )
    log, final_motor_rad, syncs = _move_and_log(tmp_path, BridgeConfig(profile=profile))
    chunks = list(read_candump_chunks(log, layout_for(AXIS.kind, DRIVES / "simdrive.toml")))
    motor = np.concatenate([c.motor_position_rad for c in chunks])
    assert abs(motor.size - syncs) <= 2  # one sample per SYNC that had its TPDOs
    assert all(c.load_position is None for c in chunks)  # no load measuring system
    inc = 2 * np.pi / (1 << 20)
    # the last TPDO was sampled one cycle before the drive's final state
    assert motor[-1] == pytest.approx(final_motor_rad, abs=max(50 * inc, 1e-4))
    assert np.ptp(motor) == pytest.approx(0.004 * AXIS.transmission_ratio, rel=0.02)
    torque = np.concatenate([c.motor_torque for c in chunks])
    assert chunks[0].torque_unit == "N·m" and np.all(np.isfinite(torque))


def test_contract_log_decodes_load_and_motor(tmp_path: Path) -> None:
    log, _, _ = _move_and_log(tmp_path, BridgeConfig())
    chunks = list(read_candump_chunks(log, CandumpLayout()))
    load = np.concatenate([c.load_position for c in chunks])
    motor = np.concatenate([c.motor_position_rad for c in chunks])
    assert np.ptp(load) == pytest.approx(0.004, rel=0.02)
    # the load follows the motor through the ball screw (k_r) within the backlash
    assert np.max(np.abs(motor / AXIS.transmission_ratio - load)) < 2 * AXIS.mechanics.backlash


def _restamped(log: Path, out: Path, cycle_s: float) -> Path:
    """The same frames stamped as a real-time run would have: one cycle from SYNC to SYNC
    (the frames after a SYNC a microsecond apart)."""
    lines, t, syncs = [], 0.0, 0
    for line in log.read_text().splitlines():
        if not line.strip():
            lines.append(line)
            continue
        _, iface, frame = line.split(" ", 2)
        if frame.startswith("080#"):
            syncs += 1
            t = 1000.0 + syncs * cycle_s
        else:
            t += 1e-6
        lines.append(f"({t:.6f}) {iface} {frame}")
    out.write_text("\n".join(lines) + "\n")
    return out


def test_a_lockstep_log_is_timed_by_its_sync_count(tmp_path: Path) -> None:
    """The in-process bus runs in lockstep, far faster than the 1 ms cycle: the monitor times
    its samples by the SYNC count (one warning saying so), and gets the same times as from the
    same frames stamped one cycle apart, where it uses the stamps and warns of nothing."""
    cycle = AXIS.control.position_cycle
    log, _, _ = _move_and_log(tmp_path, BridgeConfig())
    layout = layout_for(AXIS.kind, None, cycle)
    stamps = np.array([float(ln[1:18]) for ln in log.read_text().splitlines() if "080#" in ln])
    assert np.median(np.diff(stamps)) < 0.5 * cycle  # the premise: a lockstep log
    with pytest.warns(TimeBaseWarning, match=r"SYNC count times 1 ms") as caught:
        lockstep = np.concatenate([c.time_s for c in read_candump_chunks(log, layout)])
    assert len(caught) == 1
    np.testing.assert_allclose(np.diff(lockstep), cycle, rtol=1e-9)
    assert lockstep[0] == 0.0
    real = _restamped(log, tmp_path / "real.log", cycle)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TimeBaseWarning)
        stamped = np.concatenate([c.time_s for c in read_candump_chunks(real, layout)])
    np.testing.assert_allclose(stamped - stamped[0], lockstep, atol=1e-6)
    # without the axis's cycle the stamps are the time base, as they came
    with warnings.catch_warnings():
        warnings.simplefilter("error", TimeBaseWarning)
        raw = np.concatenate([c.time_s for c in read_candump_chunks(log, CandumpLayout())])
    assert raw[-1] - raw[0] < 0.5 * lockstep[-1]
