"""G-code-like text to contour blocks: the subset a contour of two axes needs.

One block per line, words in any order, case-insensitive::

    G01 X100 Y0 F1000        (a line to X100 Y0 at 1000 mm/min)
    G03 X0 Y100 I-100 J0     ; counter-clockwise arc, centre at start + (I, J)
    G02 X100 Y0 R100         ; not supported: give the centre with I and J

``G01`` line, ``G02`` clockwise arc, ``G03`` counter-clockwise arc (modal, as the feed ``F``);
``X``/``Y`` absolute end point in mm (G90, G21), an axis not given keeps its position; ``I``/
``J`` the arc's centre relative to its start in mm; ``F`` the feed in mm/min. ``N`` numbers,
``( ... )`` and ``; ...`` comments are skipped. An arc whose end equals its start is a full
circle. Everything else (G00, G17..G19, R, other words) is refused with the line's number:
the interpolator does what it was asked or nothing. The blocks are in load units (m, m/s).
"""

from __future__ import annotations

import re

from ..errors import ContourError
from .path import Arc, Line, Point
from .planner import Block

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_MM = 1e-3
_MM_MIN = 1e-3 / 60.0
_MOTIONS = {1: "G01", 2: "G02", 3: "G03"}


def _strip(line: str) -> str:
    line = re.sub(r"\([^)]*\)", " ", line)
    return line.split(";", 1)[0].strip()


def parse_program(text: str, start: Point = (0.0, 0.0)) -> tuple[Block, ...]:
    """The blocks of ``text`` (module docstring) from ``start`` (load units, where the axes
    stand)."""
    pos = (float(start[0]), float(start[1]))
    motion: int | None = None
    feed: float | None = None
    blocks: list[Block] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = _strip(raw)
        if not line:
            continue
        words = _WORD.findall(line)
        if _WORD.sub("", line).strip():
            raise ContourError(
                f"line {number}: {raw.strip()!r}: not a word of a letter and a number"
            )
        values: dict[str, float] = {}
        for letter, value in words:
            letter = letter.upper()
            if letter == "N":
                continue
            if letter == "G":
                g = float(value)
                if g not in (1.0, 2.0, 3.0):
                    raise ContourError(
                        f"line {number}: G{value} not supported; allowed G01, G02, G03"
                    )
                motion = int(g)
                continue
            if letter not in "XYIJF":
                raise ContourError(
                    f"line {number}: word {letter}{value} not supported; allowed G, X, Y, I, J, "
                    "F, N"
                )
            if letter in values:
                raise ContourError(f"line {number}: {letter} given twice")
            values[letter] = float(value)
        if "F" in values:
            if values["F"] <= 0:
                raise ContourError(f"line {number}: F{values['F']:g}: a feed must be > 0 mm/min")
            feed = values["F"] * _MM_MIN
        if not ({"X", "Y", "I", "J"} & set(values)):
            continue  # a line that only sets modal words
        if motion is None:
            raise ContourError(f"line {number}: a move needs G01, G02 or G03 first")
        if feed is None:
            raise ContourError(f"line {number}: no feed yet; give F (mm/min)")
        end = (
            values["X"] * _MM if "X" in values else pos[0],
            values["Y"] * _MM if "Y" in values else pos[1],
        )
        try:
            if motion == 1:
                if "I" in values or "J" in values:
                    raise ContourError("G01 takes no I or J")
                segment: Line | Arc = Line(pos, end)
            else:
                if "I" not in values and "J" not in values:
                    raise ContourError(f"{_MOTIONS[motion]} needs its centre as I and J")
                centre = (pos[0] + values.get("I", 0.0) * _MM, pos[1] + values.get("J", 0.0) * _MM)
                segment = Arc.through(pos, end, centre, ccw=motion == 3)
            blocks.append(Block(segment, feed))
        except ContourError as exc:
            raise ContourError(f"line {number}: {exc}") from None
        pos = end
    if not blocks:
        raise ContourError("the program has no move")
    return tuple(blocks)
