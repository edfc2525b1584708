"""The simulated drive with an FMU as its plant: the same CiA 402 device around an axis this
project did not write. The FMU's own failure is a drive fault (EMCY 6100h naming the FMI
call, Fault, no fault reset while the plant is dead); its torque limit is its own (a 6072h
write that would change it is aborted with 0609 0030h); with the power stage off it holds a
speed of zero (it cannot coast)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import canopen
import pytest

from plant_sim.drive import State402
from plant_sim.drive.rig import virtual_rig
from plant_sim.fmu import FmuPlant, FmuSpec, load_fmu, nominal_axis
from tests.plant_sim.drive.test_protection import EMCY, TPDO2, emcy, enable_and_run, increments
from tests.plant_sim.fmu.fmus import family_fmu, tiny_fmu
from virtual_bus.formats.axis import load_axis
from virtual_bus.shipped import PAPER_AXIS

S = State402


def test_the_drive_steps_the_fmu_once_per_sync() -> None:
    """60FFh reaches the FMU one SYNC later (the PDO delay), 6064h is its motor encoder."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=0,family=0"))
    axis = nominal_axis(model)
    with FmuPlant(model, axis) as plant, virtual_rig(axis, plant=plant) as rig:
        states = enable_and_run(rig, increments(10.0), 50)
        assert states[-1] is S.OPERATION_ENABLED
        # the drive steps after a SYNC's TPDOs: an SDO answer comes after that step (the drive
        # handles its frames in order), so the plant is read once it is done
        counts = rig.sdo.sdo[0x6064].raw
        assert plant.time_s == pytest.approx(50 * axis.control.position_cycle)
        assert plant.motor_speed_rad_s == pytest.approx(10.0, abs=0.5)
        assert counts == round(plant.motor_position_rad / (2 * math.pi) * 2**20)


def test_the_fmus_failure_is_a_drive_fault(tmp_path: Path) -> None:
    model = load_fmu(FmuSpec.from_text(tiny_fmu(tmp_path), "fail_after=20"))
    axis = load_axis(PAPER_AXIS)
    with FmuPlant(model, axis) as plant, virtual_rig(axis, plant=plant) as rig:
        states = enable_and_run(rig, increments(1.0), 30)
        assert states[19] is S.OPERATION_ENABLED
        assert states[-1] is S.FAULT
        code, register, data = emcy(rig)
        assert code == 0x6100 and register & 0x01 and data.startswith(b"DoSte")
        assert rig.sdo.sdo[0x603F].raw == 0x6100
        position = plant.motor_position_rad
        rig.probe.setpoint(0x80, 0)  # fault reset: refused while the plant is dead
        got = rig.probe.sync_and_collect([TPDO2])
        assert struct.unpack_from("<H", got[TPDO2])[0] & 0x4F == 0x08  # still Fault
        assert plant.motor_position_rad == position
        assert not [
            m for m in rig.probe.drain() if m.arbitration_id == EMCY and m.data[:2] == b"\0\0"
        ]


def test_6072h_cannot_change_an_fmus_own_torque_limit() -> None:
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=1"))
    axis = nominal_axis(model)
    with FmuPlant(model, axis) as plant, virtual_rig(axis, plant=plant) as rig:
        default = rig.sdo.sdo[0x6072].raw
        with pytest.raises(canopen.SdoAbortedError) as info:
            rig.sdo.sdo[0x6072].raw = default // 2
        assert info.value.code == 0x0609_0030
        rig.sdo.sdo[0x6072].raw = default  # the value in force: accepted
        assert rig.drive.torque_limit_nm == pytest.approx(plant.torque_limit_nm)


def test_power_stage_off_the_fmu_axis_stands_still() -> None:
    """Disabled after a move (controlword 0x06: Ready to switch on): the speed loop of the FMU
    holds zero, the axis stops instead of rolling on."""
    model = load_fmu(FmuSpec.from_text(family_fmu(), "seed=0,family=0,noise=0"))
    axis = nominal_axis(model)
    with FmuPlant(model, axis) as plant, virtual_rig(axis, plant=plant) as rig:
        enable_and_run(rig, increments(20.0), 100)
        for _ in range(300):
            rig.probe.setpoint(0x06, 0)
            rig.probe.sync_and_collect([TPDO2])
        assert abs(plant.motor_speed_rad_s) < 1e-3
