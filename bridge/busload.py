"""Bus load of the bridge's cyclic traffic (``python -m bridge busload``).

Per cycle: one SYNC (no data, the bridge sends no SYNC counter) and, per axis, the drive's
TPDO1 and TPDO2 and the bridge's RPDO1 of :data:`bridge.layout.LAYOUT`. Frame lengths with
worst-case bit stuffing from :func:`virtual_bus.bus_load` (Davis et al. 2007). Acyclic
traffic (heartbeats, EMCY, SDO) is not included: a 1-byte heartbeat every 100 ms adds
63 bits per 100 ms, well below 0.1 % at 500 kbit/s.
"""

from __future__ import annotations

from dataclasses import dataclass

from virtual_bus import CIA301_BITRATES, BusLoad, bus_load
from virtual_bus.contract import SYNC_COB_ID

from .errors import BridgeConfigError
from .layout import RPDO1, TPDO1, TPDO2


@dataclass(frozen=True)
class CyclicFrame:
    name: str
    can_id: int
    dlc: int


def cyclic_frames(drive_ids: tuple[int, ...]) -> list[CyclicFrame]:
    """SYNC plus TPDO1, TPDO2 and RPDO1 of each drive, in bus order (by CAN id)."""
    frames = [CyclicFrame("SYNC", SYNC_COB_ID, 0)]
    for drive in drive_ids:
        for spec, name in ((TPDO1, "TPDO1"), (TPDO2, "TPDO2"), (RPDO1, "RPDO1")):
            frames.append(CyclicFrame(f"{name} drive {drive}", spec.cob_id(drive), spec.dlc))
    return sorted(frames, key=lambda f: f.can_id)


def layout_load(
    axes: int, cycle_s: float, bitrate: int, first_drive_id: int = 2
) -> tuple[list[CyclicFrame], BusLoad]:
    """Frames and worst-case load of ``axes`` drives (node-IDs from ``first_drive_id``)."""
    if isinstance(axes, bool) or not isinstance(axes, int) or not 1 <= axes <= 126:
        raise BridgeConfigError(f"axes = {axes!r}: must be 1..126")
    if bitrate not in CIA301_BITRATES:
        raise BridgeConfigError(
            f"bitrate = {bitrate!r}: not a CiA 301 bit rate; allowed {list(CIA301_BITRATES)}"
        )
    last = first_drive_id + axes - 1
    if last > 127:
        raise BridgeConfigError(f"{axes} axes from node-ID {first_drive_id} exceed node-ID 127")
    frames = cyclic_frames(tuple(range(first_drive_id, last + 1)))
    return frames, bus_load([f.dlc for f in frames], cycle_s, bitrate)


def max_axes(cycle_s: float, bitrate: int, limit: float = 1.0) -> int:
    """Most axes whose cyclic frames fit into ``limit`` (fraction) of the cycle."""
    best = 0
    for axes in range(1, 126):
        _, load = layout_load(axes, cycle_s, bitrate)
        if load.load_fraction > limit:
            break
        best = axes
    return best


def report(axes: int, cycle_s: float, bitrate: int) -> str:
    """The text ``python -m bridge busload`` prints."""
    frames, load = layout_load(axes, cycle_s, bitrate)
    lines = [
        f"cyclic traffic per {cycle_s * 1e6:g} us cycle at {bitrate / 1000:g} kbit/s, "
        f"{axes} {'axis' if axes == 1 else 'axes'} (worst-case bit stuffing, 11-bit ids, "
        "interframe space included):",
        f"  {'frame':<18} {'COB-ID':>6} {'bytes':>5} {'bits':>5} {'us':>7}",
    ]
    for frame, seconds in zip(frames, load.frame_times_s, strict=True):
        bits = round(seconds * bitrate)
        lines.append(
            f"  {frame.name:<18} {frame.can_id:#6x} {frame.dlc:>5} {bits:>5} {seconds * 1e6:>7.1f}"
        )
    lines += [
        f"  total {load.bits_per_cycle} bits = {load.busy_s * 1e6:.1f} us per cycle",
        f"bus load {100 * load.load_fraction:.1f} % "
        + ("(fits)" if load.fits else "(does NOT fit into the cycle)"),
        f"axes that fit at this rate and cycle: {max_axes(cycle_s, bitrate)} (100 %), "
        f"{max_axes(cycle_s, bitrate, 0.5)} (50 %, leaving room for SDO, EMCY, heartbeats)",
    ]
    return "\n".join(lines)
