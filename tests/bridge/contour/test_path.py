"""bridge.contour.path and .program: lines and arcs against points sampled densely and
against circle geometry written out here; G-code text against the same segments built by
hand; bad segments and lines refused with what was wrong."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.contour.path import Arc, Line, check_continuous, tangent_continuous
from bridge.contour.program import parse_program
from bridge.errors import BridgeError, ContourError


def dense(segment: Line | Arc, n: int = 200_001) -> tuple[np.ndarray, np.ndarray]:
    return segment.point(np.linspace(0.0, segment.length, n))


@pytest.mark.parametrize("ccw", [True, False])
@pytest.mark.parametrize(
    ("start", "end", "centre"),
    [
        ((0.1, 0.0), (0.0, 0.1), (0.0, 0.0)),  # a quarter
        ((0.1, 0.0), (0.1, 0.0), (0.0, 0.0)),  # a full circle
        ((0.03, 0.04), (-0.05, 0.0), (0.0, 0.0)),
        ((1.0, 2.0), (1.2, 2.2), (1.2, 2.0)),
    ],
)
def test_arc_through_start_end_centre(start, end, centre, ccw: bool) -> None:
    arc = Arc.through(start, end, centre, ccw=ccw)
    r = math.dist(start, centre)
    assert arc.radius == pytest.approx(r, rel=1e-12)
    assert arc.ccw is ccw
    assert arc.start == pytest.approx(start, abs=1e-12)
    assert arc.end == pytest.approx(end, abs=1e-12)
    x, y = dense(arc)
    assert np.hypot(x - centre[0], y - centre[1]) == pytest.approx(r, abs=1e-12)
    # the direction of travel: the cross product of radius and motion has the arc's sign
    dx, dy = np.diff(x), np.diff(y)
    cross = (x[:-1] - centre[0]) * dy - (y[:-1] - centre[1]) * dx
    assert np.all(np.sign(cross) == (1 if ccw else -1))
    # the length is the polygon's through the dense points
    assert arc.length == pytest.approx(float(np.sum(np.hypot(dx, dy))), rel=1e-9)
    # bounds and the largest direction cosines against the dense points
    (x0, y0), (x1, y1) = arc.bounds()
    assert (x0, y0, x1, y1) == pytest.approx((x.min(), y.min(), x.max(), y.max()), abs=1e-9)
    cx, cy = arc.largest_direction_cosines()
    ds = np.hypot(dx, dy)
    assert cx == pytest.approx(np.max(np.abs(dx / ds)), abs=1e-5)
    assert cy == pytest.approx(np.max(np.abs(dy / ds)), abs=1e-5)


def test_a_quarter_counter_clockwise_is_the_short_way_and_clockwise_the_long() -> None:
    ccw = Arc.through((0.1, 0.0), (0.0, 0.1), (0.0, 0.0), ccw=True)
    cw = Arc.through((0.1, 0.0), (0.0, 0.1), (0.0, 0.0), ccw=False)
    assert ccw.sweep == pytest.approx(math.pi / 2)
    assert cw.sweep == pytest.approx(-3 * math.pi / 2)


def test_line_geometry_and_tangent_continuity() -> None:
    line = Line((0.0, 0.0), (0.03, 0.04))
    assert line.length == pytest.approx(0.05)
    assert line.tangent(0.0) == pytest.approx((0.6, 0.8))
    assert line.largest_direction_cosines() == pytest.approx((0.6, 0.8))
    # a line ending where a circle about (0.03, 0.09) starts, tangent to it
    arc = Arc.through((0.03, 0.04), (0.08, 0.09), (0.03, 0.09), ccw=True)
    assert not tangent_continuous(line, arc)
    tangent_line = Line((0.0, 0.04), (0.03, 0.04))
    assert tangent_continuous(tangent_line, arc)
    assert not tangent_continuous(Line((0, 0), (1, 0)), Line((1, 0), (2, 1)))


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: Line((0.0, 0.0), (0.0, 0.0)), "same point"),
        (lambda: Line((0.0, math.nan), (1.0, 0.0)), "finite"),
        (lambda: Arc.through((0.1, 0.0), (0.0, 0.2), (0.0, 0.0), ccw=True), "must be equal"),
        (lambda: Arc((0.0, 0.0), 0.0, 0.0, 1.0), "radius"),
        (lambda: Arc((0.0, 0.0), 0.1, 0.0, 0.0), "no length"),
        (lambda: check_continuous((Line((0, 0), (1, 0)), Line((1, 1), (2, 1)))), "continuous"),
        (lambda: check_continuous(()), "at least one"),
    ],
)
def test_bad_segments_are_refused(make, words: str) -> None:
    with pytest.raises(ContourError, match=words) as info:
        make()
    assert isinstance(info.value, BridgeError) and isinstance(info.value, ValueError)
    assert "\n" not in str(info.value)


def test_a_program_is_the_segments_built_by_hand() -> None:
    text = """
    N10 G01 X50 Y0 F2000 (to the start)
    G03 X0 Y50 I-50 J0   ; a quarter, counter-clockwise
    G01 X0 Y0 F1000
    G02 X0 Y0 I10 J0     ; a full circle clockwise about (10, 0) mm
    """
    blocks = parse_program(text)
    mm = 1e-3
    assert [type(b.segment) for b in blocks] == [Line, Arc, Line, Arc]
    assert blocks[0].segment == Line((0.0, 0.0), (50 * mm, 0.0))
    assert blocks[0].feed == pytest.approx(2000 * mm / 60)
    arc = blocks[1].segment
    assert arc.centre == pytest.approx((0.0, 0.0)) and arc.radius == pytest.approx(50 * mm)
    assert arc.sweep == pytest.approx(math.pi / 2) and blocks[1].feed == blocks[0].feed
    assert blocks[2].feed == pytest.approx(1000 * mm / 60)
    circle = blocks[3].segment
    assert circle.sweep == pytest.approx(-2 * math.pi) and circle.centre == pytest.approx((0.01, 0))


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("G00 X1 Y1 F100", "line 1: G00 not supported"),
        ("G01 X1 Y1", "no feed"),
        ("X1 Y1 F100", "needs G01, G02 or G03"),
        ("G01 X1 Y1 F100\nG02 X2 Y2 F100", "line 2: G02 needs its centre"),
        ("G01 X1 Y1 F100\nG02 X2 Y1 I0 J5", "line 2: arc from"),
        ("G01 X1 Y1 F100 Z3", "word Z3 not supported"),
        ("G01 X1 X2 F100", "X given twice"),
        ("G01 X1 Y1 F-5", "feed must be > 0"),
        ("G01 X1 Y1 F100 hello", "not a word"),
        ("(nothing)\n; at all", "no move"),
    ],
)
def test_bad_program_lines_are_refused_with_their_number(text: str, words: str) -> None:
    with pytest.raises(ContourError, match=words) as info:
        parse_program(text)
    assert "\n" not in str(info.value)
