"""The paper's section X scenario and the sweep over k_v and δ (what the CLI runs).

Section X: speed step of the interpolator, δ = 0.1 mm, a 6280 N disturbance force (20 N·m at
the motor) on the load from 2 s to 4 s in the direction of motion, once with the ordinary
control (Fig. 1, Fig. 8) and once with the speed regulator (Fig. 6, Fig. 9).

The paper leaves the feed speed and the end of the run out. Chosen here: a step to
``FEED_M_S`` = 0.05 m/s (3 m/min, a milling feed) at t = 0, constant feed until
``STOP_S`` = 6 s (the paper's 6 s window), then the interpolator stops and the axis is watched
at standstill until ``END_S`` = 7 s ("final standstill error").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from regulator import RegulatorConfig
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace

from ..physics.model import KernelOptions
from ..physics.simulate import References, simulate

FEED_M_S = 0.05  # load units/s, the speed step of section X
DISTURBANCE_FORCE_N = 6280.0  # section X: "step disturbance force of 6280 N"
DISTURBANCE_START_S = 2.0
DISTURBANCE_END_S = 4.0
STOP_S = 6.0
END_S = 7.0
#: Section X reports the vibration "for the rest of motion" after the disturbance; the
#: peak-to-peak following error is measured over [P2P_START_S, STOP_S).
P2P_START_S = 4.5


@dataclass(frozen=True)
class SectionX:
    """Parameters of the section X run (defaults: the paper's values and the choices above)."""

    feed: float = FEED_M_S
    disturbance_force_n: float = DISTURBANCE_FORCE_N
    disturbance_start_s: float = DISTURBANCE_START_S
    disturbance_end_s: float = DISTURBANCE_END_S
    stop_s: float = STOP_S
    end_s: float = END_S

    def references(self, axis: AxisConfig) -> References:
        """Position/speed reference and disturbance, one value per position cycle."""
        cycle = axis.control.position_cycle
        n = round(self.end_s / cycle)
        t = np.arange(n) * cycle
        moving = t < self.stop_s
        speed = np.where(moving, self.feed, 0.0)
        position = np.concatenate([[0.0], np.cumsum(speed[:-1]) * cycle])
        # the force pushes in the direction of motion (to open the gap, section X)
        torque = np.sign(self.feed) * self.disturbance_force_n / axis.transmission_ratio
        dist = np.where((t >= self.disturbance_start_s) & (t < self.disturbance_end_s), torque, 0.0)
        return References(position, speed, dist)


def run_section_x(
    axis: AxisConfig,
    with_regulator: bool,
    scenario: SectionX = SectionX(),
    regulator: RegulatorConfig | None = None,
    options: KernelOptions = KernelOptions(),
) -> Trace:
    """One run of section X: ordinary control (Fig. 8) or with the regulator (Fig. 9)."""
    base = regulator or RegulatorConfig(kv=axis.control.kv, cycle_s=axis.control.position_cycle)
    reg = dataclasses.replace(base, enabled=with_regulator)
    return simulate(axis, scenario.references(axis), reg, options)
