"""A drive's DCF that carries its supervision of the bridge (``bridge probe --dcf``).

The bridge's start-up writes the drive's supervision of the bridge (:mod:`bridge.supervision`:
1016h heartbeat consumer, 6007h abort connection option code, a set-point watchdog) and gives
the old values back at an orderly end. A plant that wants the drive to watch the bridge from
power-on -- or a commissioning tool that configures drives from DCFs rather than from the
bridge -- needs those values in the drive's CiA 306 device configuration file. This module
writes it: the drive's EDS with ``ParameterValue`` on exactly the objects the start-up would
write (nothing else: every other object keeps what the drive has), and the commissioning
section. ``bridge config load FILE.dcf [--save]`` (or any CiA 306 tool) puts it in the drive;
the bridge's start-up then finds the entry already watching it and reuses it.

CiA 301 (7.2.8.3.2): a heartbeat consumer starts watching with the first heartbeat it
receives, so a drive with this entry stored does not fault while no bridge has started.
"""

from __future__ import annotations

from pathlib import Path

import canopen
from canopen.objectdictionary import ODVariable

from ..errors import CommissionInputError
from ..supervision import Supervision
from .access import decode, value_text
from .dcf import Commissioning, SectionKey, key_of, render_dcf


def _variable(od: canopen.ObjectDictionary, index: int, subindex: int) -> ODVariable | None:
    if index not in od.indices:
        return None
    obj = od[index]
    if isinstance(obj, ODVariable):
        return obj if subindex == 0 else None
    return obj[subindex] if subindex in obj.subindices else None


def supervision_values(
    od: canopen.ObjectDictionary, supervision: Supervision, eds: Path
) -> dict[SectionKey, str]:
    """The DCF values (section key -> ParameterValue text) of the start-up's supervision
    writes; CommissionInputError when the drive writes none or the EDS lacks one of them (the
    DCF could not carry it)."""
    if not supervision.writes:
        raise CommissionInputError(
            "the drive has none of 1016h, 6007h or a set-point watchdog: there is no "
            "supervision of the bridge to put in a DCF"
        )
    values: dict[SectionKey, str] = {}
    for write in supervision.writes:
        index, sub = write.key
        var = _variable(od, index, sub)
        if var is None:
            raise CommissionInputError(
                f"{eds}: has no {index:04X}h:{sub:02X}, which the start-up writes "
                f"({write.what}): the DCF cannot carry it (is it the drive's EDS?)"
            )
        values[key_of(var, od)] = value_text(var, decode(var, write.data))
    return values


def supervision_dcf(
    eds: Path,
    od: canopen.ObjectDictionary,
    supervision: Supervision,
    *,
    drive_id: int,
    bitrate: int,
    dcf_name: str,
    node_name: str,
) -> str:
    """The DCF text (module docstring) for the drive at ``drive_id`` on a bus of ``bitrate``
    bit/s."""
    values = supervision_values(od, supervision, eds)
    try:
        text = eds.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise CommissionInputError(f"{eds}: cannot read the EDS ({exc})") from None
    return render_dcf(
        text,
        eds_name=eds.name,
        dcf_name=dcf_name,
        values=values,
        commissioning=Commissioning(
            node_id=drive_id, node_name=node_name, baudrate_kbit=bitrate // 1000
        ),
    )
