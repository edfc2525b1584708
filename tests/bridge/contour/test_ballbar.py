"""bridge.contour.ballbar and .planner against circles whose errors are written out here
analytically (the axes' positions of a circle with a centre offset, unequal scales, a
squareness error, unequal lags, a lost motion), and the planner's reference against the circle
and the limits it was given."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.contour import (
    AxisLimits,
    CircularTest,
    Direction,
    MeasuredPath,
    PathLimits,
    analyse,
    plan,
)
from bridge.errors import ContourError

R, F = 0.05, 1.0 / 60
TEST = CircularTest(R, F)


def path(
    d: Direction,
    *,
    centre=(0.0, 0.0),
    scale=(0.0, 0.0),
    gamma=0.0,
    lag=(0.0, 0.0),
    lost=(0.0, 0.0),
) -> MeasuredPath:
    """One direction's circle with the errors given: the load positions and, with ``lost``,
    motor positions that lead the load by half the gap in the direction of travel."""
    t = np.linspace(0.0, 2 * math.pi * R / F, 20_000, endpoint=False)
    w = d.sign * F / R
    x = R * np.cos(w * (t - lag[0]))
    y = R * np.sin(w * (t - lag[1]))
    x, y = (1 + scale[0]) * x + gamma * y + centre[0], (1 + scale[1]) * y + centre[1]
    vx, vy = np.gradient(x), np.gradient(y)
    mx = x + 0.5 * lost[0] * np.sign(vx)
    my = y + 0.5 * lost[1] * np.sign(vy)
    return MeasuredPath(d, x, y, mx, my)


def both(**kw) -> tuple[MeasuredPath, MeasuredPath]:
    return path(Direction.CCW, **kw), path(Direction.CW, **kw)


def test_a_perfect_circle_names_nothing() -> None:
    r = analyse(TEST, both())
    assert r.named == () and r.spikes == ()
    assert r.contour_error < 1e-9 and r.hysteresis < 1e-9


def test_centre_offset_and_scale_mismatch_and_squareness() -> None:
    r = analyse(TEST, both(centre=(20e-6, -10e-6)))
    assert r.named == ("centre offset",)
    assert r.signature("centre offset").value == pytest.approx(math.hypot(20e-6, 10e-6), rel=0.01)
    r = analyse(TEST, both(scale=(100e-6, 0.0)))  # 100 µm/m on X
    assert r.named == ("scale mismatch",)
    assert r.signature("scale mismatch").value == pytest.approx(100.0, rel=0.02)
    r = analyse(TEST, both(gamma=200e-6))
    assert "squareness" in r.named and "servo mismatch" not in r.named
    assert r.signature("squareness").value == pytest.approx(200.0, rel=0.02)


def test_unequal_lags_are_servo_mismatch_not_squareness() -> None:
    """x lags its command by 1/k_v of 10/s, y by that of 11/s: the tilt changes with the
    direction (squareness's does not)."""
    tx, ty = 1 / 10, 1 / 11
    r = analyse(TEST, both(lag=(tx, ty)))
    assert r.named[0] == "servo mismatch" and "squareness" not in r.named
    assert r.signature("servo mismatch").value == pytest.approx(1e3 * (tx - ty), rel=0.02)


def test_lost_motion_is_the_gap() -> None:
    r = analyse(TEST, both(lost=(50e-6, 0.0)), windup_per_nm={})
    assert r.lost_motion["X"] == pytest.approx(50e-6, rel=1e-3)
    assert r.lost_motion["Y"] == pytest.approx(0.0, abs=1e-9)


def test_one_path_or_two_of_the_same_direction() -> None:
    assert analyse(TEST, [path(Direction.CW)]).bidirectional_deviation is None
    with pytest.raises(ContourError, match="both directions"):
        analyse(TEST, [path(Direction.CW), path(Direction.CW)])


LIMITS = [AxisLimits("X", -1.0, 1.0, 0.5, 2.0), AxisLimits("Y", -1.0, 1.0, 0.5, 2.0)]


@pytest.mark.parametrize("d", list(Direction))
def test_the_planned_circle_is_on_the_circle_at_the_feed(d: Direction) -> None:
    ref = plan(TEST.blocks(d), LIMITS, PathLimits(0.5), 1e-3)
    x, y = ref.position[:, 0], ref.position[:, 1]
    assert np.hypot(x, y) == pytest.approx(R, abs=1e-12)
    speed = np.hypot(ref.speed[:, 0], ref.speed[:, 1])
    assert speed.max() == pytest.approx(F, rel=1e-3)
    assert np.all(speed <= F * (1 + 1e-9))
    # the data arc runs at the feed and sweeps 360° in the direction asked
    data = TEST.data_mask(ref)
    assert speed[data][:-1] == pytest.approx(F, rel=1e-3)
    a = np.unwrap(np.arctan2(y[data], x[data]))
    assert d.sign * (a[-1] - a[0]) == pytest.approx(2 * math.pi, abs=0.01)
    assert ref.speed[-1].tolist() == [0.0, 0.0]


TRAVEL = r"load units, outside the travel limits of axis Y \[.*\] load units"
SPEED = r"above its speed limit .*; allowed feed <= \S+ load units/s"


def test_planner_refuses_what_the_axes_cannot_do() -> None:
    with pytest.raises(ContourError, match=TRAVEL):
        plan(CircularTest(0.05, F, (0.0, 0.98)).blocks(Direction.CCW), LIMITS, PathLimits(1), 1e-3)
    with pytest.raises(ContourError, match=SPEED):
        plan(CircularTest(0.05, 0.6).blocks(Direction.CCW), LIMITS, PathLimits(1), 1e-3)
    with pytest.raises(ContourError, match="centripetal"):
        plan(CircularTest(0.01, 0.3).blocks(Direction.CCW), LIMITS, PathLimits(1), 1e-3)


def test_a_program_with_corners_stops_at_each_and_keeps_every_limit() -> None:
    """A square with a rounded corner, read from G-code: the path passes exactly through the
    programmed points, stands still at every sharp corner (exact stop), runs the tangent
    line-arc join without stopping, and no axis exceeds its speed or acceleration limit
    (second differences of the samples; the jerk filter on)."""
    from bridge.contour.program import parse_program

    text = """
    G01 X20 Y0 F3000
    G03 X30 Y10 I0 J10
    G01 X30 Y30
    G01 X0 Y30
    G01 X0 Y0
    """
    blocks = parse_program(text)
    limits = [AxisLimits("X", -0.1, 0.1, 0.06, 0.8), AxisLimits("Y", -0.1, 0.1, 0.06, 0.8)]
    T = 1e-3
    ref = plan(blocks, limits, PathLimits(0.5, jerk=20.0), T)
    pos, v = ref.position, ref.speed
    for corner in ((0.03, 0.03), (0.0, 0.03)):  # sharp corners: at rest there
        k = int(np.argmin(np.hypot(pos[:, 0] - corner[0], pos[:, 1] - corner[1])))
        assert math.dist(pos[k], corner) < 1e-9
        assert np.hypot(*v[k]) < 1e-4 and np.hypot(*v[k - 1]) < 1e-4  # 0.2 % of the feed
    join = int(np.argmin(np.hypot(pos[:, 0] - 0.02, pos[:, 1])))  # line into arc: tangent
    assert np.hypot(*v[join]) == pytest.approx(0.05, rel=1e-3)  # 3000 mm/min, no stop
    assert np.all(np.abs(v) <= 0.06 * (1 + 1e-9))
    acc = np.diff(v, axis=0) / T
    assert np.max(np.abs(acc)) <= 0.8 * (1 + 1e-6)
    assert pos[-1].tolist() == pytest.approx([0.0, 0.0], abs=1e-12)
