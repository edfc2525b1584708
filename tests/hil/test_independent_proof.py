"""Issue 18's proof against what the project did not write: the beta_T the procedure finds on
the project's simulated axis, applied to the independently written plant
(reference_plants/independent: RK4, smoothed friction, a damped contact, a PI current loop,
quantised encoders) with that plant's own modelling choices, cuts the section X limit cycle by
at least 90 % and keeps the standstill error; compared with the optimum of a grid search over
beta_T on that plant. The frequency response on that plant finds its antiresonance within the
stated uncertainty.

The regulator in the loop is the bridge's own classes (regulator.PositionController,
BacklashRegulator) with the one-cycle PDO delay (hil.loop); only the plant is foreign.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.commission.freqresp import ExcitationPlan
from bridge.commission.tune import TuneOptions, axis_limits, make_ladder
from hil.loop import run_loop, trial_runner
from hil.offline import frequency_response, safety_of, tune_offline
from plant_sim.fmu.arguments import AxisSource
from plant_sim.paper.outputs import LIMIT_CYCLE_VISCOUS
from plant_sim.paper.scenarios import SectionX
from reference_plants.independent import SteppedPlant
from regulator import RegulatorConfig
from regulator.frequency_response import Multisine
from regulator.tuning import Outcome, search
from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisConfig, load_axis

pytestmark = pytest.mark.slow


PAPER = load_axis(CONFIG / "paper_axis.toml")
#: section X's limit cycle exists with the viscous friction of the paper's figures
LIMIT_CYCLE = PAPER.with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
CYCLE_S, KV = PAPER.control.position_cycle, PAPER.control.kv
KR = PAPER.transmission_ratio


def _section_x(axis: AxisConfig, beta_t: float | None) -> tuple[float, float]:
    """(peak-to-peak following error over 4.5..6 s, |standstill error| over the last 0.1 s)
    of section X on the independent plant, the regulator at beta_t (None: off)."""
    refs = SectionX().references(axis)
    reg = RegulatorConfig(
        kv=KV, cycle_s=CYCLE_S, beta_t_rad_s=beta_t or 0.2, enabled=beta_t is not None
    )
    tr = run_loop(SteppedPlant(axis), refs.position, refs.speed, KR, reg, 0.0, refs.disturbance_nm)
    e = tr.position_reference - tr.load_position
    t = np.arange(e.size) * CYCLE_S
    return float(np.ptp(e[(t >= 4.5) & (t < 6.0)])), abs(float(np.mean(e[-100:])))


def _found_on_the_kernel() -> float:
    """The procedure on the project's own simulated axis (what `hil tune` runs)."""
    source = AxisSource(LIMIT_CYCLE, "limit cycle")
    result = tune_offline(source, TuneOptions(torque_limit=150.0), 0.01)
    assert result.outcome is Outcome.FOUND, result.reason
    assert result.beta_t_rad_s is not None
    return result.beta_t_rad_s


def test_beta_t_found_on_the_kernel_cuts_the_independent_plants_limit_cycle() -> None:
    beta_t = _found_on_the_kernel()
    ordinary_p2p, ordinary_standstill = _section_x(LIMIT_CYCLE, None)
    assert ordinary_p2p > 100e-6  # the independent plant's own limit cycle (README: 119 µm)
    p2p, standstill = _section_x(LIMIT_CYCLE, beta_t)
    cut = 1.0 - p2p / ordinary_p2p
    assert cut >= 0.90, (beta_t, p2p, ordinary_p2p)
    # the standstill error is kept: within 10 % (or 20 nm, the plant's 5 nm scale) of the
    # ordinary control's, which is exact at standstill
    assert standstill <= max(1.1 * ordinary_standstill, ordinary_standstill + 20e-9)
    # the grid search over beta_T on the same plant: its optimum, and where the found value
    # stands against it
    grid = np.geomspace(0.02, 20.0, 16)
    results = [_section_x(LIMIT_CYCLE, b) for b in grid]
    keeps = [r[1] <= max(1.1 * ordinary_standstill, ordinary_standstill + 20e-9) for r in results]
    best = min((r[0], b) for r, b, k in zip(results, grid, keeps, strict=True) if k)
    optimum_cut = 1.0 - best[0] / ordinary_p2p
    # within 10 points of the grid's best (it may beat the grid, which is coarse)
    assert cut >= optimum_cut - 0.1
    assert best[1] / 4 <= beta_t <= best[1] * 4  # the same region, not another regime


def test_the_procedure_on_the_independent_plant_finds_a_beta_t_that_works_there() -> None:
    """The procedure itself run on the foreign plant (its trials on that plant): found, and
    its beta_T cuts that plant's section X limit cycle by at least 90 %."""
    options = TuneOptions(torque_limit=150.0)
    safety = safety_of(LIMIT_CYCLE, 0.01, 150.0)
    limits = axis_limits(LIMIT_CYCLE, options, 0.01, (safety.position_min, safety.position_max))
    run = trial_runner(
        lambda start: SteppedPlant(LIMIT_CYCLE, position=start),
        KR,
        RegulatorConfig(kv=KV, cycle_s=CYCLE_S),
        safety,
    )
    ladder = make_ladder(options, limits, 0.0, True, "")
    result = search(run, ladder, options.search, CYCLE_S, KV, options.standstill_limit)
    assert result.outcome is Outcome.FOUND, result.reason
    assert result.beta_t_rad_s is not None
    ordinary_p2p, _ = _section_x(LIMIT_CYCLE, None)
    p2p, _ = _section_x(LIMIT_CYCLE, result.beta_t_rad_s)
    assert 1.0 - p2p / ordinary_p2p >= 0.90


def test_the_independent_plants_antiresonance_within_the_stated_uncertainty() -> None:
    """The paper's axis with its backlash closed by a constant load torque of 20 N m (a weight)
    and a slow feed of 6 mm/s (no speed reversal): the notch of the speed loop measured on the
    independent plant holds its omega_a = sqrt(k / M) = 600 rad/s within the stated interval,
    and the interval is no wider than 5 % of it."""
    axis = PAPER.with_values({"disturbance.constant_torque": 20.0})
    plan = ExcitationPlan(
        Multisine(CYCLE_S, 1024, 1.0, 450.0, 1.0, corner_hz=20.0),
        periods=3,
        realizations=8,
        offset_speed=0.006,
        torque_limit=150.0,
    )
    fr = frequency_response(SteppedPlant(axis), plan, KR, KV)
    notch = fr.antiresonance
    truth = axis.mechanics.antiresonance
    assert truth == 600.0
    assert notch.resolved and notch.contains(truth), (notch.rad_s, notch.uncertainty_rad_s)
    assert notch.uncertainty_rad_s < 0.05 * truth
    assert math.isfinite(fr.bandwidth.frequency_hz)
