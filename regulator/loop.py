"""The position loop around any steppable axis, cycle by cycle in Python (paper Fig. 1, Fig. 6).

:func:`play` closes :func:`regulator.cycle.position_cycle` around an axis that has
``advance(speed_setpoint_rad_s, disturbance_nm)`` and the readings ``motor_position_rad``,
``motor_speed_rad_s``, ``load_position`` and ``motor_torque_nm`` (the compiled kernel's plant,
an FMU's, the tests' independent plants). Per position cycle k: the sensors are read at t_k;
the cycle computes the set point; the set point computed at cycle k takes effect at k + 1
with ``delay_cycles = 1`` (a CANopen bridge's PDO delay) or at once with 0; the plant runs one
position cycle. A limit the cycle stops on (its block's 2008h/2009h/2014h) ends the control:
the set point is 0 from then on (``stop_code``, ``stop_cycle`` say when and why).

Units: load units (m or rad), rad/s and N·m at the motor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from . import core, cycle

#: The samples :func:`play` records, one per cycle (the simulator's trace column names).
COLUMNS = (
    "position_reference",
    "speed_setpoint",
    "motor_position",
    "motor_speed",
    "load_position",
    "motor_torque",
    "disturbance",
    "beta",
    "lambda",
    "omega_s",
    "omega_c",
)


class SteppedAxis(Protocol):
    """An axis a position loop closes around, what :func:`play` steps (module docstring).
    Structural: any object with these members is one (the kernel's plant, an FMU's, the
    reference plants); :class:`plant_sim.plant.Plant` is one plus what a drive needs."""

    def advance(self, speed_setpoint_rad_s: float, disturbance_nm: float = 0.0) -> None: ...

    @property
    def motor_position_rad(self) -> float: ...

    @property
    def motor_speed_rad_s(self) -> float: ...

    @property
    def load_position(self) -> float: ...

    @property
    def motor_torque_nm(self) -> float: ...


@dataclass(frozen=True)
class LoopRun:
    """What :func:`play` recorded: ``samples`` (:data:`COLUMNS`, one value per cycle), and
    the cycle's stop (``stop_code`` :data:`regulator.cycle.OK` when it ran to the end)."""

    samples: dict[str, np.ndarray]
    stop_code: int = cycle.OK
    stop_cycle: int | None = None
    stop_feedback: float = 0.0
    stop_difference: float = 0.0

    def __getitem__(self, column: str) -> np.ndarray:
        return self.samples[column]


def play(
    axis: SteppedAxis,
    position: np.ndarray,
    speed: np.ndarray,
    block: Any,
    disturbance_nm: np.ndarray | None = None,
    *,
    delay_cycles: int = 1,
    motor_feedback: bool = False,
) -> LoopRun:
    """Play the reference (load units and load units/s per cycle) on ``axis`` with the cycle
    block ``block`` (:func:`regulator.cycle.block`, its results updated in place);
    ``motor_feedback``: the loop closes on motor position / k_r instead of the load scale."""
    if delay_cycles not in (0, 1):
        raise ValueError(f"delay_cycles = {delay_cycles}: allowed 0 or 1")
    n = len(position)
    c = block
    det = [0.0] * core.detector_state_size(int(c[cycle.C_REG_N]))
    dist = np.zeros(n) if disturbance_nm is None else np.asarray(disturbance_nm, dtype=float)
    out = np.empty((len(COLUMNS), n))
    kr = c[cycle.C_KR]
    latched = 0.0  # the set point in force during this cycle
    code, stop_cycle = cycle.OK, None
    stop_fb = stop_diff = 0.0
    at_start = axis.motor_position_rad / kr - axis.load_position
    for k in range(n):
        x_l, theta = axis.load_position, axis.motor_position_rad
        x_fb = theta / kr if motor_feedback else x_l
        if stop_cycle is None:
            difference = theta / kr - x_l - at_start
            code = cycle.position_cycle(c, det, position[k], speed[k], x_fb, difference, True)
            if code != cycle.OK:
                stop_cycle, stop_fb, stop_diff = k, x_fb, difference
        omega_r = c[cycle.Y_OMEGA_R] if stop_cycle is None else 0.0
        out[:, k] = (
            position[k],
            omega_r,
            theta,
            axis.motor_speed_rad_s,
            x_l,
            axis.motor_torque_nm,
            dist[k],
            c[cycle.Y_BETA],
            c[cycle.Y_LAMBDA],
            c[cycle.Y_OMEGA_S],
            c[cycle.Y_OMEGA_C],
        )
        if delay_cycles:
            axis.advance(latched, float(dist[k]))
            latched = omega_r
        else:
            axis.advance(omega_r, float(dist[k]))
    samples = dict(zip(COLUMNS, out, strict=True))
    return LoopRun(samples, code, stop_cycle, stop_fb, stop_diff)


@dataclass(frozen=True)
class AxesRun:
    """What :func:`play_axes` recorded: one :class:`LoopRun` per axis (a stop of any axis
    stops them all at the same cycle: a contour is left whole or not at all), and
    ``stopped_axis``, the index of the axis whose cycle stopped (None: ran to the end)."""

    axes: tuple[LoopRun, ...]
    stopped_axis: int | None = None

    def __getitem__(self, i: int) -> LoopRun:
        return self.axes[i]


def play_axes(
    axes: Sequence[SteppedAxis],
    positions: Sequence[np.ndarray],
    speeds: Sequence[np.ndarray],
    blocks: Sequence[Any],
    *,
    shared_lambda: bool = False,
    speed_offsets: Sequence[np.ndarray | None] | None = None,
    delay_cycles: int = 1,
    motor_feedback: bool = False,
) -> AxesRun:
    """Several axes interpolated together, cycle by cycle in lockstep: per cycle every axis's
    sensors are read, its cycle computed (:func:`play`'s order), then every axis is stepped.

    ``shared_lambda``: the axes share eq. 15's lambda (:func:`regulator.cycle.shared_lambda`,
    the smallest of their own), so a shaking axis fades the load scale out of all of them
    alike (paper section II.A, eq. 1); otherwise each axis runs
    :func:`regulator.cycle.position_cycle` on its own, exactly as :func:`play` (the same
    bits). ``speed_offsets``: per axis None or a motor speed (rad/s per cycle) added to the
    set point after the cycle, clamped again to the axis's 2007h (a reversal compensation).
    A stop of one axis's cycle sets every axis's set point to 0 from then on."""
    if delay_cycles not in (0, 1):
        raise ValueError(f"delay_cycles = {delay_cycles}: allowed 0 or 1")
    m = len(axes)
    if not (len(positions) == len(speeds) == len(blocks) == m) or m == 0:
        raise ValueError("one position, speed and cycle block per axis")
    n = len(positions[0])
    offsets = list(speed_offsets) if speed_offsets is not None else [None] * m
    dets = [[0.0] * core.detector_state_size(int(c[cycle.C_REG_N])) for c in blocks]
    outs = [np.empty((len(COLUMNS), n)) for _ in range(m)]
    krs = [c[cycle.C_KR] for c in blocks]
    starts = [a.motor_position_rad / kr - a.load_position for a, kr in zip(axes, krs, strict=True)]
    latched = [0.0] * m
    codes = [cycle.OK] * m
    stops: list[int | None] = [None] * m
    stop_fb, stop_diff = [0.0] * m, [0.0] * m
    stopped: int | None = None
    reads: list[tuple[float, float, float, float]] = [(0.0, 0.0, 0.0, 0.0)] * m
    for k in range(n):
        for i, (axis, c) in enumerate(zip(axes, blocks, strict=True)):
            x_l, theta = axis.load_position, axis.motor_position_rad
            reads[i] = (x_l, theta, axis.motor_speed_rad_s, axis.motor_torque_nm)
            if stopped is not None:
                continue
            x_fb = theta / krs[i] if motor_feedback else x_l
            difference = theta / krs[i] - x_l - starts[i]
            args = (positions[i][k], speeds[i][k], x_fb, difference, True)
            code = (cycle.measure if shared_lambda else cycle.position_cycle)(c, dets[i], *args)
            if code != cycle.OK:
                codes[i], stops[i], stop_fb[i], stop_diff[i] = code, k, x_fb, difference
                stopped = i
        if stopped is None and shared_lambda:
            lam = cycle.shared_lambda(blocks)
            for c in blocks:
                cycle.apply(c, lam)
        for i, (axis, c) in enumerate(zip(axes, blocks, strict=True)):
            omega_r = c[cycle.Y_OMEGA_R] if stopped is None else 0.0
            extra = offsets[i]
            if extra is not None and stopped is None:
                limit = c[cycle.C_SPEED_LIMIT]
                omega_r = min(max(omega_r + float(extra[k]), -limit), limit)
            x_l, theta, w, tq = reads[i]
            outs[i][:, k] = (
                positions[i][k],
                omega_r,
                theta,
                w,
                x_l,
                tq,
                0.0,
                c[cycle.Y_BETA],
                c[cycle.Y_LAMBDA],
                c[cycle.Y_OMEGA_S],
                c[cycle.Y_OMEGA_C],
            )
            if delay_cycles:
                axis.advance(latched[i], 0.0)
                latched[i] = omega_r
            else:
                axis.advance(omega_r, 0.0)
    runs = tuple(
        LoopRun(
            dict(zip(COLUMNS, outs[i], strict=True)), codes[i], stops[i], stop_fb[i], stop_diff[i]
        )
        for i in range(m)
    )
    return AxesRun(runs, stopped)
