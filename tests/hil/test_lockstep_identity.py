"""Lockstep over the bus is bit-identical to the stepped loop without a bus.

The lockstep path (bridge loop, python-can virtual bus or vcan0, the simulated drive's PDO
engine and CiA 402 machine, the candump log and the trace file) is tuned for throughput
(docs/bridge.md, "Lockstep"); none of that may change a single bit of what goes over the bus
or into the trace. The reference is computed on a second path that shares none of the bus
code: the pure :class:`~bridge.cycle.CycleController` stepped against an ``AxisPlant`` behind
the contract's PDO scaling (tests/bridge_helpers.PayloadDrive, packing its own frames). Every
frame of every cycle in the candump log (SYNC, TPDO1, TPDO2, RPDO: id, order and payload) and
every column of the trace must be equal, not close. The ordinary run (limit cycle) is chaotic:
any change of the arithmetic on either side shows up within a few hundred cycles.
"""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from bridge.cycle import BridgeState, CycleController
from bridge.interpolator import Table
from bridge.layout import SYNC_COB_ID, TPDO2_STRUCT
from bridge.params import BridgeParams
from bridge.scaling import MOTOR_INCREMENTS_PER_RAD, Scaling
from hil.harness import play_references
from plant_sim.drive import DriveConfig
from tests.bridge.test_loop import limit_cycle_over_bus, params
from tests.bridge_helpers import LIMIT_CYCLE_AXIS, PayloadDrive  # tests/ helper module
from virtual_bus import Interface
from virtual_bus.formats.trace import read_trace

DRIVE_ID = 2
#: CiA 402 statusword of a drive in Operation enabled (xxxx xxxx x01x 0111 = 0x0027) with
#: voltage enabled (bit 4), remote (bit 9) and "drive follows the command value" (bit 12)
STATUSWORD_RUNNING = 0x0027 | 1 << 4 | 1 << 9 | 1 << 12
#: 6076h of the simulated drive (the bridge reads it at start-up; torque in ‰ of it)
RATED_TORQUE_NM = DriveConfig().rated_torque_nm
CYCLE_IDS = (SYNC_COB_ID, 0x180 + DRIVE_ID, 0x280 + DRIVE_ID, 0x200 + DRIVE_ID)
#: trace column -> attribute of the stepped controller after its step
COLUMNS = {
    "position_reference": "position_reference",
    "speed_setpoint": "omega_r",
    "motor_position": "motor_position_rad",
    "motor_speed": "motor_speed_rad_s",
    "load_position": "load_position",
    "motor_torque": "motor_torque_nm",
    "beta": "vibration_level",
    "lambda": "switching_factor",
    "omega_s": "omega_s",
    "omega_c": "omega_c",
    "following_error": "following_error",
    "motor_load_difference": "motor_load_difference",
}


class Payloads(PayloadDrive):
    """PayloadDrive with the simulated drive's rated torque and statusword in TPDO2: bit 11
    (internal limit active) while |torque| >= 0.999 · the axis' limit (docs/drive.md,
    statusword extras)."""

    def tpdos(self) -> tuple[bytes, bytes]:
        tpdo1, _ = super().tpdos()
        p = self.plant
        limit_nm = LIMIT_CYCLE_AXIS.control.torque_limit
        at_limit = limit_nm is not None and abs(p.motor_torque_nm) >= 0.999 * limit_nm
        tpdo2 = TPDO2_STRUCT.pack(
            STATUSWORD_RUNNING | (1 << 11 if at_limit else 0),
            round(p.motor_torque_nm * 1000.0 / RATED_TORQUE_NM),
            round(p.motor_speed_rad_s * MOTOR_INCREMENTS_PER_RAD),
        )
        return tpdo1, tpdo2


def stepped(enabled: bool, refs) -> tuple[list[tuple[int, bytes]], dict[str, np.ndarray]]:
    """Frames (id, payload) per cycle and trace columns of the loop without a bus."""
    p: BridgeParams = params(LIMIT_CYCLE_AXIS, enabled)
    c = CycleController(p, Scaling.for_kind(LIMIT_CYCLE_AXIS.kind, RATED_TORQUE_NM))
    c.queue_move(Table.from_references(refs))
    drive = Payloads(LIMIT_CYCLE_AXIS)
    n = refs.position.size
    frames: list[tuple[int, bytes]] = []
    columns = {name: np.empty(n) for name in COLUMNS}
    for k in range(n):
        tpdo1, tpdo2 = drive.tpdos()
        rpdo = bytes(c.step(k * c.params.cycle_s, tpdo1, tpdo2))
        frames += [(SYNC_COB_ID, b""), (CYCLE_IDS[1], tpdo1), (CYCLE_IDS[2], tpdo2)]
        frames.append((CYCLE_IDS[3], rpdo))
        for name, attr in COLUMNS.items():
            columns[name][k] = getattr(c, attr)
        drive.advance(rpdo, refs.disturbance_nm[k])
    return frames, columns


def logged_cycle_frames(path: Path) -> list[tuple[int, bytes]]:
    """The cycle's frames in the candump log, from the first SYNC on (heartbeats left out)."""
    frames = [(m.arbitration_id, bytes(m.data)) for m in can.CanutilsLogReader(str(path))]
    first = next(i for i, (cid, _) in enumerate(frames) if cid == SYNC_COB_ID)
    return [f for f in frames[first:] if f[0] in CYCLE_IDS]


@pytest.mark.parametrize("enabled", [False, True], ids=["ordinary", "regulated"])
def test_lockstep_frames_and_trace_are_those_of_the_stepped_loop(
    bus_mode: Interface, enabled: bool, tmp_path: Path
) -> None:
    with limit_cycle_over_bus(
        enabled,
        bus_mode,
        trace_path=tmp_path / "trace.csv",
        keep_trace=False,
        bus_log_path=tmp_path / "bus.log",
    ) as (refs, sim):
        run = play_references(sim, refs)
    assert run.state is BridgeState.RUNNING and run.counters.missed == 0
    frames, columns = stepped(enabled, refs)
    logged = logged_cycle_frames(tmp_path / "bus.log")
    assert len(logged) == len(frames) == 4 * refs.position.size
    first_difference = next(
        (i for i, (a, b) in enumerate(zip(logged, frames, strict=True)) if a != b), None
    )
    assert first_difference is None, (
        f"cycle {first_difference // 4}: logged {logged[first_difference]}, "
        f"stepped {frames[first_difference]}"
    )
    trace = read_trace(tmp_path / "trace.csv")  # written with repr: floats round-trip exactly
    np.testing.assert_array_equal(trace["time"], np.arange(refs.position.size) * 0.001)
    for name, values in columns.items():
        np.testing.assert_array_equal(trace[name], values, err_msg=name)
    np.testing.assert_array_equal(trace["disturbance"], refs.disturbance_nm)
