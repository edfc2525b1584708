"""The circular test offline: two simulated axes (an FMU's or the compiled kernel's)
interpolating a circle through the bridge's position cycle, and the ballbar report of the
path they took (:mod:`bridge.contour`).

Per position cycle both axes are read, each axis's cycle is computed
(:func:`regulator.cycle.position_cycle`, or its halves when the axes share eq. 15's lambda)
and both are stepped: :func:`regulator.loop.play_axes`, the one composition of the bridge's
cycle, with the bridge's limits (2007h clamp, 2008h, 2009h, 2014h) and the one-cycle PDO
delay. Four ways to control the contour (:class:`Control`, paper section II.A and eq. 15):

* ``ordinary`` -- eq. 7 on both axes, the regulator off;
* ``regulator`` -- the regulator on one axis alone (its own lambda: its dynamics change while
  it fades the load scale out, the other axis's do not -- eq. 1 is broken while it acts);
* ``shared`` -- the regulator on both axes with one lambda, the smallest
  (:func:`regulator.cycle.shared_lambda`): both fade together, eq. 1 holds;
* ``compensation`` -- eq. 7 with a CNC's backlash compensation on each axis
  (:class:`bridge.contour.compensation.ReversalCompensation`) of the backlash an ordinary
  test measured (the machine datum, never the plant's truth).

Everything a user can measure decides: the gain, limits and stiffness come from the axis
files (for an FMU its data sheet), the backlash from the ordinary test's lost motion.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bridge.contour import (
    AxisLimits,
    BallbarReport,
    CircularTest,
    Direction,
    MeasuredPath,
    PathLimits,
    analyse,
    plan,
)
from bridge.contour.axes import ContourAxes, ContourAxis
from bridge.contour.compensation import ReversalCompensation
from bridge.errors import ContourError
from bridge.params import BridgeParams
from plant_sim.fmu.arguments import AxisSource
from regulator import RegulatorConfig, cycle
from regulator.loop import AxesRun, play_axes
from virtual_bus.formats.axis import AxisConfig

#: Cycles the axes stand at the start before the circle and after it.
SETTLE_CYCLES = 300
#: Share of the torque limit the contour's acceleration may use (the rest: friction, margin).
ACCEL_TORQUE_SHARE = 0.5
#: Acceleration allowed of an axis whose file states no torque limit (load units/s²).
UNLIMITED_ACCEL = 10.0


class Control(enum.Enum):
    """How the contour axes are controlled (module docstring)."""

    ORDINARY = "ordinary"
    REGULATOR = "regulator"
    SHARED = "shared"
    COMPENSATION = "compensation"

    @property
    def title(self) -> str:
        return {
            Control.ORDINARY: "ordinary control (eq. 7)",
            Control.REGULATOR: "regulator on the backlash axis",
            Control.SHARED: "regulator, shared λ",
            Control.COMPENSATION: "backlash compensation",
        }[self]


def axis_limits(
    axis: AxisConfig, name: str, travel: tuple[float, float] | None = None
) -> AxisLimits:
    """What the bridge lets ``axis`` do on a contour: its travel (2014h, default the bridge's
    for the axis kind), speed (the 2007h clamp over k_r) and acceleration (a share of its
    torque limit over the inertia at the motor)."""
    p = BridgeParams.for_axis(axis)
    lo, hi = travel if travel is not None else (p.position_limit_min, p.position_limit_max)
    kr = axis.transmission_ratio
    accel = UNLIMITED_ACCEL
    torque = axis.control.torque_limit
    if torque:
        inertia = axis.motor_side_inertia + axis.load_inertia_reflected
        accel = ACCEL_TORQUE_SHARE * torque / (inertia * kr)
    return AxisLimits(name, lo, hi, p.speed_limit_rad_s / kr, accel)


@dataclass(frozen=True)
class ContourSetup:
    """Two simulated axes (x, y) and their contour control.

    ``kv``: the position gain of each axis (1/s; eq. 1 asks for equal ones -- a mismatch is
    what the servo mismatch of the report shows); ``regulated``: the axis the ``regulator``
    control regulates (0 = x); ``beta_t_rad_s``: the regulator's threshold (eq. 15, the
    bridge's 2011h); ``path_accel``: the path's acceleration limit (load units/s²)."""

    sources: tuple[AxisSource, AxisSource]
    axes: ContourAxes
    kv: tuple[float, float]
    regulated: int = 0
    beta_t_rad_s: float | None = None
    path_accel: float = 1.0
    compensation_cycles: int = 5

    def __post_init__(self) -> None:
        if len(self.sources) != 2 or len(self.kv) != 2:
            raise ContourError("a contour setup has two axes (x, y) and a k_v for each")
        for name, kv in zip("xy", self.kv, strict=True):
            if not (isinstance(kv, int | float) and math.isfinite(kv) and kv > 0):
                raise ContourError(f"k_v of axis {name} = {kv!r}: must be a finite number > 0")
        if self.regulated not in (0, 1):
            raise ContourError(f"regulated axis {self.regulated!r}: allowed 0 (x) or 1 (y)")
        cycles = {s.axis.control.position_cycle for s in self.sources}
        if len(cycles) != 1:
            raise ContourError(
                f"the axes' position cycles differ ({sorted(cycles)} s): interpolating axes "
                "run on one SYNC"
            )

    @classmethod
    def of(
        cls,
        sources: Sequence[AxisSource],
        *,
        kv: Sequence[float] | None = None,
        node_ids: tuple[int, int] = (2, 3),
        travel: Sequence[tuple[float, float] | None] = (None, None),
        **kw: object,
    ) -> ContourSetup:
        """A setup of two sources; ``kv`` default: the smaller of their axis files' k_v on
        both (a CNC gives its contour axes the gain the slower one allows, eq. 1)."""
        if len(sources) != 2:
            raise ContourError(f"a planar contour has two axes, not {len(sources)}")
        if kv is None:
            common = min(s.axis.control.kv for s in sources)
            kv = (common, common)
        axes = ContourAxes(
            tuple(
                ContourAxis(axis_limits(s.axis, name, t), n)
                for s, name, t, n in zip(sources, "XY", travel, node_ids, strict=True)
            )
        )
        return cls((sources[0], sources[1]), axes, (float(kv[0]), float(kv[1])), **kw)  # type: ignore[arg-type]

    @property
    def cycle_s(self) -> float:
        return self.sources[0].axis.control.position_cycle

    def block(self, i: int, regulator_on: bool) -> list[float]:
        """Axis ``i``'s cycle block with the bridge's limits (as :func:`hil.loop.run_loop`)."""
        axis = self.sources[i].axis
        extra = {} if self.beta_t_rad_s is None else {"beta_t_rad_s": self.beta_t_rad_s}
        reg = RegulatorConfig(kv=self.kv[i], cycle_s=self.cycle_s, enabled=regulator_on, **extra)
        p = BridgeParams.for_axis(axis, reg)
        lim = self.axes.axes[i].limits
        return cycle.block(
            axis.transmission_ratio,
            reg.kv,
            reg.cycle_s,
            velocity_feedforward=axis.control.velocity_feedforward or 0.0,
            regulator_on=reg.enabled,
            n=reg.n,
            tv_s=reg.effective_tv_s,
            tf_s=reg.tf_s,
            beta_t_rad_s=reg.beta_t_rad_s,
            speed_limit_rad_s=p.speed_limit_rad_s,
            following_error_limit=p.following_error_limit,
            discrepancy_limit=p.discrepancy_limit,
            position_min=lim.position_min,
            position_max=lim.position_max,
        )

    def windup_per_nm(self) -> dict[str, float]:
        """Per axis the elastic wind-up per N·m at the motor, k_r / stiffness (data sheet)."""
        out = {}
        for name, s in zip("XY", self.sources, strict=True):
            if s.axis.stiffness:
                out[name] = s.axis.transmission_ratio / s.axis.stiffness
        return out


@dataclass(frozen=True)
class CircularRun:
    """One control's circular test: the report, both directions' paths and loop runs."""

    control: Control
    test: CircularTest
    report: BallbarReport
    paths: tuple[MeasuredPath, ...]
    runs: tuple[AxesRun, ...]


def run_direction(
    setup: ContourSetup,
    test: CircularTest,
    direction: Direction,
    control: Control,
    backlash: dict[str, float] | None = None,
) -> tuple[MeasuredPath, AxesRun]:
    """One direction of the test on fresh plants at the lead-in's start."""
    limits = PathLimits(setup.path_accel)
    ref = plan(test.blocks(direction), setup.axes.limits, limits, setup.cycle_s)
    n0 = SETTLE_CYCLES
    pos = [
        np.concatenate(
            (np.full(n0, ref.position[0, i]), ref.position[:, i], np.full(n0, ref.position[-1, i]))
        )
        for i in range(2)
    ]
    spd = [np.concatenate((np.zeros(n0), ref.speed[:, i], np.zeros(n0))) for i in range(2)]
    regulated = {
        Control.ORDINARY: (False, False),
        Control.COMPENSATION: (False, False),
        Control.REGULATOR: tuple(i == setup.regulated for i in range(2)),
        Control.SHARED: (True, True),
    }[control]
    blocks = [setup.block(i, regulated[i]) for i in range(2)]
    offsets: list[np.ndarray | None] = [None, None]
    if control is Control.COMPENSATION:
        for i, name in enumerate("XY"):
            b = (backlash or {}).get(name, 0.0)
            comp = ReversalCompensation(b, setup.compensation_cycles)
            kr = setup.sources[i].axis.transmission_ratio
            # the axis reverses when its lagging position loop does, 1/k_v after its
            # reference (eq. 7 without feed-forward: following error = speed / k_v)
            ff = setup.sources[i].axis.control.velocity_feedforward or 0.0
            lag = round((1.0 - ff) / (setup.kv[i] * setup.cycle_s))
            shifted = np.concatenate((np.zeros(lag), spd[i][: spd[i].size - lag]))
            offsets[i] = comp.speed_offset(shifted, kr, setup.cycle_s)
    plants = [s.plant(float(pos[i][0]), f"axis {'xy'[i]}") for i, s in enumerate(setup.sources)]
    try:
        run = play_axes(
            plants,
            pos,
            spd,
            blocks,
            shared_lambda=control is Control.SHARED,
            speed_offsets=offsets,
        )
    finally:
        for p in plants:
            p.close()
    if run.stopped_axis is not None:
        stop = run[run.stopped_axis]
        raise ContourError(
            f"axis {'XY'[run.stopped_axis]} stopped at cycle {stop.stop_cycle} (cycle code "
            f"{stop.stop_code}): the circle was left unfinished"
        )
    mask = np.concatenate((np.zeros(n0, bool), test.data_mask(ref), np.zeros(n0, bool)))
    krs = [s.axis.transmission_ratio for s in setup.sources]
    path = MeasuredPath(
        direction,
        run[0]["load_position"][mask],
        run[1]["load_position"][mask],
        run[0]["motor_position"][mask] / krs[0],
        run[1]["motor_position"][mask] / krs[1],
        run[0]["motor_torque"][mask],
        run[1]["motor_torque"][mask],
    )
    return path, run


def check(
    setup: ContourSetup, test: CircularTest, directions: Sequence[Direction] = tuple(Direction)
) -> None:
    """Plan every direction of ``test`` on the setup's axes: :class:`ContourError` (one line)
    for a circle outside an axis's travel, a feed above an axis's speed or acceleration
    limits -- before any plant is made or stepped."""
    for d in directions:
        plan(test.blocks(d), setup.axes.limits, PathLimits(setup.path_accel), setup.cycle_s)


def circular_test(
    setup: ContourSetup,
    test: CircularTest,
    control: Control = Control.ORDINARY,
    directions: Sequence[Direction] = (Direction.CCW, Direction.CW),
    backlash: dict[str, float] | None = None,
) -> CircularRun:
    """The circular test in ``directions`` with ``control``; the report of the paths.
    ``compensation`` needs ``backlash`` (per axis "X"/"Y", load units: what a test measured)."""
    if control is Control.COMPENSATION and backlash is None:
        raise ContourError("backlash compensation needs the backlash a circular test measured")
    check(setup, test, directions)
    done = [run_direction(setup, test, d, control, backlash) for d in directions]
    paths = tuple(p for p, _ in done)
    report = analyse(test, paths, windup_per_nm=setup.windup_per_nm())
    return CircularRun(control, test, report, paths, tuple(r for _, r in done))


def compare(setup: ContourSetup, test: CircularTest) -> dict[Control, CircularRun]:
    """The four controls on the same axes and circle; compensation uses the backlash the
    ordinary test measured (its lost motion less the wind-up)."""
    ordinary = circular_test(setup, test, Control.ORDINARY)
    out = {Control.ORDINARY: ordinary}
    for control in (Control.REGULATOR, Control.SHARED):
        out[control] = circular_test(setup, test, control)
    out[Control.COMPENSATION] = circular_test(
        setup, test, Control.COMPENSATION, backlash=dict(ordinary.report.backlash)
    )
    return out
