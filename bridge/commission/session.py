"""Tests the bridge runs on a drive for commissioning (frequency response, beta_T tuning).

Both work on a started :class:`~bridge.node.Bridge` -- any drive the start-up adapted to --
through what a tool could do over SDO: disable (2020h = 2), change locked parameters, enable
(2020h = 1), queue motion, watch the cycle. Motion is a :class:`~bridge.interpolator.Table`
played by the interpolator like any other move, so the cycle's supervision (2008h, 2009h,
2014h, heartbeats, EMCY, the drive's state) stays in force; :class:`Recorder` samples the
controller after every cycle and stops the axis (:attr:`StopReason.TEST_LIMIT`) when the
test's own torque limit is exceeded. Nothing here imports the simulator.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..cycle import BridgeState, Command, CycleController, StopReason
from ..errors import BridgeError
from ..interpolator import Table
from ..node import Bridge
from ..params import BridgeParams

if TYPE_CHECKING:
    from regulator.tuning import Record

log = logging.getLogger("bridge")

#: Cycles the drive gets to reach Operation Enabled after an enable command (the cycle's own
#: enable timeout, 1 s, stops the axis earlier on a real drive).
ENABLE_CYCLES = 5000


class CommissioningStopped(BridgeError, RuntimeError):
    """The axis stopped during a commissioning test; ``reason`` is the stop reason."""

    def __init__(self, message: str, *, reason: StopReason) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass
class Recording:
    """Per-cycle samples of a test (SI: load units, rad/s at the motor, N m or per mille):
    the bridge's over the bus, and :func:`hil.loop.run_loop`'s without a bus."""

    position_reference: np.ndarray
    load_position: np.ndarray
    omega_r: np.ndarray
    motor_speed: np.ndarray
    torque: np.ndarray
    beta: np.ndarray
    switching_factor: np.ndarray
    cycles: int = 0
    #: why the loop stopped the axis (:func:`hil.loop.run_loop`), None when it did not
    stop_reason: str | None = None

    @classmethod
    def empty(cls, size: int) -> Recording:
        return cls(*(np.full(size, math.nan) for _ in range(7)))

    def trimmed(self) -> Recording:
        n = self.cycles
        return Recording(
            self.position_reference[:n],
            self.load_position[:n],
            self.omega_r[:n],
            self.motor_speed[:n],
            self.torque[:n],
            self.beta[:n],
            self.switching_factor[:n],
            n,
            self.stop_reason,
        )

    def record(self, stopped: str | None = None) -> Record:
        """What the beta_T search judges of these samples (:class:`regulator.tuning.Record`)."""
        from regulator.tuning import Record

        return Record(
            self.position_reference,
            self.load_position,
            self.beta,
            self.switching_factor,
            stopped,
            self.torque,
        )


class Recorder:
    """Samples the controller after each cycle; stops the axis above ``torque_limit``."""

    def __init__(self, controller: CycleController, size: int, torque_limit: float) -> None:
        self.c = controller
        self.rec = Recording.empty(size)
        self.torque_limit = torque_limit

    def __call__(self) -> None:
        c, r = self.c, self.rec
        k = r.cycles
        if k >= r.load_position.size:
            return
        r.position_reference[k] = c.position_reference
        r.load_position[k] = c.load_position
        r.omega_r[k] = c.omega_r
        r.motor_speed[k] = c.motor_speed_rad_s
        r.torque[k] = c.motor_torque_nm
        r.beta[k] = c.vibration_level
        r.switching_factor[k] = c.switching_factor
        r.cycles = k + 1
        if abs(c.motor_torque_nm) > self.torque_limit and c.state is BridgeState.RUNNING:
            c.stop(
                StopReason.TEST_LIMIT,
                f"torque {c.motor_torque_nm:.4g} {c.scaling.torque_unit} beyond the test's "
                f"limit {self.torque_limit:g}",
            )


def stopped_error(c: CycleController, what: str) -> CommissioningStopped:
    return CommissioningStopped(
        f"{what}: axis stopped: {c.stop_reason.name}: {c.stop_message}", reason=c.stop_reason
    )


def disable(bridge: Bridge) -> None:
    """Disable the axis (a stopped axis stays stopped) and latch it with two cycles."""
    c = bridge.controller
    if c.state in (BridgeState.RUNNING, BridgeState.ENABLING):
        c.command(Command.DISABLE)
    bridge.run(cycles=2)


def enable(bridge: Bridge, params: BridgeParams, what: str) -> None:
    """Disable, apply ``params`` (locked ones may change now), enable and wait until
    RUNNING; CommissioningStopped if the axis stops instead."""
    c = bridge.controller
    if c.state is BridgeState.STOPPED:
        raise stopped_error(c, what)
    disable(bridge)
    c.set_params(params)
    c.command(Command.ENABLE)
    bridge.run(cycles=ENABLE_CYCLES, until=lambda b: b.controller.state is not BridgeState.ENABLING)
    if c.state is not BridgeState.RUNNING:
        raise stopped_error(c, what)


def play(
    bridge: Bridge,
    table: Table,
    torque_limit: float,
    what: str,
    after: Callable[[], None] | None = None,
) -> Recording:
    """Queue ``table`` (refused with the reason when its path leaves 2014h), run one cycle
    per sample, record each; returns the recording, trimmed where the axis stopped (check
    ``bridge.controller.state``)."""
    c = bridge.controller
    c.queue_move(table)  # ParameterError 0609 0031/32 when the path leaves 2014h
    recorder = Recorder(c, table.position.size, torque_limit)

    def step(b: Bridge) -> bool:
        recorder()
        if after is not None:
            after()
        return b.controller.state is not BridgeState.RUNNING

    bridge.run(cycles=table.position.size, until=step)
    if c.state is BridgeState.STOPPED:
        log.error("%s stopped after %d cycles: %s", what, recorder.rec.cycles, c.stop_message)
    return recorder.rec.trimmed()
