"""Worst-case CAN 2.0 frame lengths and the bus load of a cyclic frame set.

Frame length with worst-case bit stuffing after R. I. Davis, A. Burns, R. J. Bril,
J. J. Lukkien, "Controller Area Network (CAN) schedulability analysis: refuted, revisited and
revised", Real-Time Systems 35(3), 2007, eq. (1)/(2)::

    C = (g + 8 s + 13 + floor((g + 8 s - 1) / 4)) * tau_bit

with s data bytes, g = 34 (11-bit identifier) or 54 (29-bit identifier): g + 8 s bits from the
start-of-frame bit to the end of the CRC are subject to stuffing (one stuff bit after the
first 5 equal bits, then after every further 4 in the worst case), 13 bits are not (CRC
delimiter, ACK slot and delimiter, 7-bit end of frame, 3-bit interframe space).

Hence, including the interframe space: standard frame 8 s + 47 + floor((33 + 8 s) / 4) bits
(0 bytes: 55, 8 bytes: 135); extended 8 s + 67 + floor((53 + 8 s) / 4) (0 bytes: 80,
8 bytes: 160). Without stuffing: 8 s + 47 and 8 s + 67.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from virtual_bus.errors import BusLoadError

#: Bits subject to stuffing without the data field (SOF .. CRC): 11-bit and 29-bit ids.
STUFFED_HEADER_BITS_STANDARD = 34
STUFFED_HEADER_BITS_EXTENDED = 54
#: CRC delimiter 1 + ACK slot 1 + ACK delimiter 1 + end of frame 7.
UNSTUFFED_TRAILER_BITS = 10
INTERFRAME_SPACE_BITS = 3
MAX_DLC = 8


def _check_dlc(dlc: int) -> None:
    if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= MAX_DLC:
        raise BusLoadError(f"dlc must be an int 0..{MAX_DLC} (CAN 2.0 data bytes), got {dlc!r}")


def worst_case_stuff_bits(stuffable_bits: int) -> int:
    """Maximum stuff bits inserted into ``stuffable_bits`` bits: floor((n - 1) / 4)."""
    if stuffable_bits < 1:
        raise BusLoadError(f"stuffable_bits must be >= 1, got {stuffable_bits}")
    return (stuffable_bits - 1) // 4


def frame_bits(dlc: int, extended: bool = False, worst_case: bool = True) -> int:
    """Bits on the wire of one CAN 2.0A (``extended=False``) or 2.0B data frame with ``dlc``
    data bytes, including the 3-bit interframe space; with worst-case stuffing (Davis et al.
    2007, eq. (1)) or without any stuff bits (``worst_case=False``, the minimum length)."""
    _check_dlc(dlc)
    header = STUFFED_HEADER_BITS_EXTENDED if extended else STUFFED_HEADER_BITS_STANDARD
    stuffable = header + 8 * dlc
    stuffing = worst_case_stuff_bits(stuffable) if worst_case else 0
    return stuffable + stuffing + UNSTUFFED_TRAILER_BITS + INTERFRAME_SPACE_BITS


@dataclass(frozen=True)
class BusLoad:
    """Load of a frame set sent once per cycle.

    bits_per_cycle: sum of frame lengths in bits. load_fraction: bits_per_cycle /
    (bitrate * cycle_s); above 1 the set does not fit. frame_times_s: transmission time of each
    frame in seconds, in input order. busy_s: their sum.
    """

    bits_per_cycle: int
    load_fraction: float
    frame_times_s: tuple[float, ...]
    busy_s: float
    cycle_s: float
    bitrate: int

    @property
    def fits(self) -> bool:
        """Whether the frames fit into one cycle (load_fraction <= 1)."""
        return self.load_fraction <= 1.0


def bus_load(
    frames_per_cycle: Sequence[int],
    cycle_s: float,
    bitrate: int = 500_000,
    *,
    extended: bool = False,
    worst_case: bool = True,
) -> BusLoad:
    """Bus load of frames with the given data lengths (dlc, 0..8 each) sent every ``cycle_s``
    seconds at ``bitrate`` bit/s (any positive rate; :class:`BusConfig` restricts to CiA 301)."""
    if isinstance(frames_per_cycle, str | bytes) or not isinstance(frames_per_cycle, Sequence):
        raise BusLoadError(
            f"frames_per_cycle must be a sequence of dlc values, got {frames_per_cycle!r}"
        )
    for dlc in frames_per_cycle:
        _check_dlc(dlc)
    if not isinstance(cycle_s, int | float) or not (math.isfinite(cycle_s) and cycle_s > 0):
        raise BusLoadError(f"cycle_s must be finite and > 0 s, got {cycle_s!r}")
    if isinstance(bitrate, bool) or not isinstance(bitrate, int) or bitrate <= 0:
        raise BusLoadError(f"bitrate must be a positive int in bit/s, got {bitrate!r}")
    bits = [frame_bits(dlc, extended, worst_case) for dlc in frames_per_cycle]
    total = sum(bits)
    times_s = tuple(b / bitrate for b in bits)
    return BusLoad(
        bits_per_cycle=total,
        load_fraction=total / (bitrate * cycle_s),
        frame_times_s=times_s,
        busy_s=total / bitrate,
        cycle_s=float(cycle_s),
        bitrate=bitrate,
    )
