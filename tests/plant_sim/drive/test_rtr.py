"""Remote frames for the drive's TPDOs (CiA 301 7.2.2 remotely requested PDOs; 1800h-1803h
sub-index 1 bit 30: 0 = RTR allowed on this PDO, 1 = not).

The drive's EDS gives TPDO1/TPDO2 bit 30 = 0, so an RTR on 0x182 asks for TPDO1: in NMT
Operational the drive answers with the present values of the mapped objects (those of the last
SYNC). With bit 30 = 1, or outside Operational (no PDOs, CiA 301 table 46), the RTR is refused
and counted in 2105h:05. Checked with a second python-can end of the bus and python canopen's
SDO client on python-can's virtual bus and on vcan0.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

import can
import pytest

from plant_sim.drive.rig import Rig, virtual_rig
from virtual_bus.contract import NmtCommand
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")
REMOTE_REFUSED = (0x2105, 5)


@pytest.fixture
def rig() -> Iterator[Rig]:
    with virtual_rig(AXIS) as rig:
        rig.probe.nmt(NmtCommand.START)
        rig.probe.sync()
        rig.probe.expect(rig.probe.tpdo_id(1))
        rig.probe.drain()
        yield rig


def rtr(rig: Rig, can_id: int, dlc: int = 8) -> None:
    rig.probe.bus.send(
        can.Message(arbitration_id=can_id, is_remote_frame=True, dlc=dlc, is_extended_id=False)
    )


def refused(rig: Rig) -> int:
    return rig.sdo.sdo[REMOTE_REFUSED[0]][REMOTE_REFUSED[1]].raw  # type: ignore[no-any-return]


def test_rtr_on_a_tpdo_with_bit_30_clear_is_answered_with_the_present_values(rig: Rig) -> None:
    tpdo1 = rig.probe.tpdo_id(1)
    assert rig.sdo.sdo[0x1800][1].raw & 0x4000_0000 == 0  # the EDS allows RTR
    rtr(rig, tpdo1)
    answer = rig.probe.expect(tpdo1)
    position = rig.sdo.sdo[0x6064].raw
    load = rig.sdo.sdo[0x60E4][1].raw
    assert bytes(answer.data) == struct.pack("<ii", position, load)
    assert not answer.is_remote_frame
    assert refused(rig) == 0


def test_rtr_refused_where_bit_30_is_set_or_outside_operational(rig: Rig) -> None:
    tpdo1, tpdo2 = rig.probe.tpdo_id(1), rig.probe.tpdo_id(2)
    rig.sdo.sdo[0x1800][1].raw = 0x4000_0000 | tpdo1  # no RTR on TPDO1 (CAN id unchanged)
    rtr(rig, tpdo1)
    assert refused(rig) == 1  # read after the RTR was handled (one receive thread)
    rig.probe.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
    rtr(rig, tpdo2)
    assert refused(rig) == 2
    assert not [m for m in rig.probe.drain() if m.arbitration_id in (tpdo1, tpdo2)]
