"""Worst-case CAN frame lengths (Davis et al. 2007) against hand values and against a
bit-level second implementation (frame encoder with CRC-15 and a real bit stuffer)."""

from __future__ import annotations

import itertools
import math
import random

import pytest

from virtual_bus import BusLoadError, bus_load, frame_bits
from virtual_bus.busload import worst_case_stuff_bits

# ------------------------------------------------------------ hand-computed values
#
# Standard frame, s data bytes: SOF 1 + id 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + 8s + CRC 15
# = 34 + 8s stuffable bits; + CRC delimiter 1 + ACK 2 + EOF 7 + interframe space 3 = 13.
#   s = 8: 98 + floor(97/4) = 98 + 24 stuff + 13 = 135;  s = 0: 34 + floor(33/4) = 8 -> 55.
# Extended: SOF 1 + base id 11 + SRR 1 + IDE 1 + ext id 18 + RTR 1 + r1 1 + r0 1 + DLC 4
# + 8s + CRC 15 = 54 + 8s stuffable.
#   s = 8: 118 + floor(117/4) = 29 -> 160;  s = 0: 54 + floor(53/4) = 13 -> 80.


@pytest.mark.parametrize(
    ("dlc", "extended", "worst_case", "bits"),
    [
        (8, False, True, 135),
        (0, False, True, 55),
        (1, False, True, 65),  # 42 stuffable, floor(41/4) = 10 -> 42 + 10 + 13
        (8, True, True, 160),
        (0, True, True, 80),
        (8, False, False, 111),
        (0, False, False, 47),
        (8, True, False, 131),
        (0, True, False, 67),
    ],
)
def test_hand_computed_frame_lengths(dlc: int, extended: bool, worst_case: bool, bits: int) -> None:
    assert frame_bits(dlc, extended=extended, worst_case=worst_case) == bits


@pytest.mark.parametrize("dlc", range(9))
@pytest.mark.parametrize(("extended", "g"), [(False, 34), (True, 54)])
def test_matches_davis_2007_equation_1(dlc: int, extended: bool, g: int) -> None:
    """C = g + 8s + 13 + floor((g + 8s - 1) / 4) bits (Davis, Burns, Bril, Lukkien 2007)."""
    assert frame_bits(dlc, extended) == g + 8 * dlc + 13 + math.floor((g + 8 * dlc - 1) / 4)


# --------------------------------------------------- second implementation: bit level


def stuff(bits: list[int]) -> list[int]:
    """CAN bit stuffing: after 5 equal consecutive bits (stuff bits included) insert the
    complement."""
    out: list[int] = []
    run_bit, run_len = None, 0
    for b in bits:
        out.append(b)
        run_len = run_len + 1 if b == run_bit else 1
        run_bit = b
        if run_len == 5:
            out.append(1 - b)
            run_bit, run_len = 1 - b, 1
    return out


def crc15(bits: list[int]) -> int:
    """CAN CRC-15, generator x^15+x^14+x^10+x^8+x^7+x^4+x^3+1 (0x4599), init 0."""
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def to_bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - k)) & 1 for k in range(width)]


def encode_frame(can_id: int, data: bytes, extended: bool) -> list[int]:
    """The stuffable part of a data frame (SOF .. CRC) as transmitted before stuffing."""
    if extended:
        head = [0, *to_bits(can_id >> 18, 11), 1, 1, *to_bits(can_id & 0x3FFFF, 18), 0, 0, 0]
    else:
        head = [0, *to_bits(can_id, 11), 0, 0, 0]
    body = head + to_bits(len(data), 4) + [b for byte in data for b in to_bits(byte, 8)]
    return body + to_bits(crc15(body), 15)


def wire_bits(can_id: int, data: bytes, extended: bool) -> int:
    return len(stuff(encode_frame(can_id, data, extended))) + 10 + 3


def test_crc15_check_value() -> None:
    """CRC-15/CAN of ASCII "123456789" is 0x059E (reveng catalogue check value)."""
    bits = [b for byte in b"123456789" for b in to_bits(byte, 8)]
    assert crc15(bits) == 0x059E


def test_stuffer_inserts_after_five_equal_bits() -> None:
    assert stuff([0] * 5) == [0, 0, 0, 0, 0, 1]
    assert stuff([0, 0, 0, 0, 0, 1, 1, 1, 1]) == [0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 0]
    assert stuff([0, 1] * 10) == [0, 1] * 10


@pytest.mark.parametrize("n", range(1, 15))
def test_worst_case_stuff_bound_is_exact_by_exhaustion(n: int) -> None:
    """Over all 2^n bit strings the most stuff bits is exactly floor((n - 1) / 4)."""
    worst = max(len(stuff(list(bits))) - n for bits in itertools.product((0, 1), repeat=n))
    assert worst == worst_case_stuff_bits(n)


@pytest.mark.parametrize("extended", [False, True])
def test_real_frames_lie_between_the_bounds(extended: bool) -> None:
    rng = random.Random(2007)
    for _ in range(2000):
        dlc = rng.randrange(9)
        can_id = rng.randrange(1 << (29 if extended else 11))
        data = bytes(rng.choice((0x00, 0xFF, rng.randrange(256))) for _ in range(dlc))
        bits = wire_bits(can_id, data, extended)
        assert frame_bits(dlc, extended, worst_case=False) <= bits <= frame_bits(dlc, extended)


def test_stuffing_of_a_hand_counted_prefix() -> None:
    """SOF, id 0x000, RTR, IDE, r0 are 15 dominant bits: a recessive stuff bit after every 5
    (each stuff bit ends the zero run) -> 3 stuff bits. The worst case needs the bits after a
    stuff bit to *equal* it (00000 1111 0000 ...), which gives one per 4 bits instead."""
    prefix = encode_frame(0x000, b"", extended=False)[:15]
    assert prefix == [0] * 15
    assert stuff(prefix) == ([0] * 5 + [1]) * 3
    worst = [0] * 5 + [1] * 4 + [0] * 4 + [1] * 2  # 15 bits
    assert len(stuff(worst)) - 15 == 3 == worst_case_stuff_bits(15)


# ---------------------------------------------------------------------- bus load


def test_bus_load_hand_values() -> None:
    # 4 frames x 8 bytes every 1 ms at 500 kbit/s: 4 x 135 = 540 bits > 500 bits per cycle.
    load = bus_load([8, 8, 8, 8], cycle_s=1e-3, bitrate=500_000)
    assert load.bits_per_cycle == 540
    assert load.load_fraction == pytest.approx(1.08)
    assert load.frame_times_s == pytest.approx((270e-6,) * 4)
    assert not load.fits
    # one SYNC (0 bytes) + two 8-byte PDOs every 2 ms at 1 Mbit/s: 55 + 270 = 325 bits.
    load = bus_load([0, 8, 8], cycle_s=2e-3, bitrate=1_000_000)
    assert load.bits_per_cycle == 325
    assert load.load_fraction == pytest.approx(325 / 2000)
    assert load.fits


def test_bus_load_is_consistent() -> None:
    load = bus_load([3, 0, 8, 5], cycle_s=4e-3, bitrate=250_000, extended=True)
    assert load.busy_s == pytest.approx(sum(load.frame_times_s))
    assert load.load_fraction == pytest.approx(load.busy_s / load.cycle_s)
    assert load.bits_per_cycle == sum(frame_bits(d, extended=True) for d in (3, 0, 8, 5))
    empty = bus_load([], cycle_s=1e-3)
    assert (empty.bits_per_cycle, empty.load_fraction, empty.frame_times_s) == (0, 0.0, ())


def test_no_stuffing_load_is_the_lower_bound() -> None:
    frames = [8, 8, 2, 0]
    low = bus_load(frames, 1e-3, worst_case=False)
    high = bus_load(frames, 1e-3)
    assert low.bits_per_cycle == sum(47 + 8 * d for d in frames)
    assert low.load_fraction < high.load_fraction


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"frames_per_cycle": [9]}, "dlc"),
        ({"frames_per_cycle": [-1]}, "dlc"),
        ({"frames_per_cycle": [True]}, "dlc"),
        ({"frames_per_cycle": "88"}, "sequence"),
        ({"cycle_s": 0.0}, "cycle_s"),
        ({"cycle_s": math.nan}, "cycle_s"),
        ({"bitrate": 0}, "bitrate"),
        ({"bitrate": 5e5}, "bitrate"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict[str, object], text: str) -> None:
    args: dict[str, object] = {"frames_per_cycle": [8], "cycle_s": 1e-3, "bitrate": 500_000}
    args.update(kwargs)
    with pytest.raises(BusLoadError, match=text) as info:
        bus_load(**args)  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError)
