"""Bounded multi-start simulation-error fitting (diagnosis/fit.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis.errors import DiagnosisOptionError
from diagnosis.evidence import data_scales
from diagnosis.fit import (
    PERIODIC_COS,
    PERIODIC_SIN,
    DiscreteParameter,
    FitSpec,
    Objective,
    Parameter,
    axis_with,
    fit,
)
from diagnosis.parameters import parameter_for
from diagnosis.replay import prepare_replay
from diagnosis.synthetic import slide_axis
from plant_sim.physics.model import KernelOptions
from plant_sim.physics.simulate import References, simulate
from virtual_bus.formats.axis import AxisConfig
from virtual_bus.formats.trace import Trace


def truth_axis() -> AxisConfig:
    return slide_axis()


def recording(axis: AxisConfig, seconds: float = 6.0) -> Trace:
    cycle = axis.control.position_cycle
    t = np.arange(round(seconds / cycle)) * cycle
    x = 0.03 * np.sin(2 * np.pi * t / 1.5) + 0.02 * np.sin(2 * np.pi * t / 0.7)
    sim = simulate(axis, References.from_position(x, cycle), options=KernelOptions(substeps=1))
    cols = ("time", "position_reference", "motor_position", "motor_speed", "motor_torque")
    return Trace({c: sim[c][::2] for c in cols})


def objective(axis: AxisConfig, rec: Trace) -> Objective:
    inp = prepare_replay(rec, axis)
    scales = {s: float(np.std(inp.compared(s))) for s in inp.signals}
    return Objective(inp, np.ones(inp.n_samples, dtype=bool), scales)


def test_parameter_transforms_and_bounds() -> None:
    p = Parameter("mechanics.load_mass", 10.0, 40.0, 25.0, 20.0, log=True)
    assert p.from_u(p.to_u(33.0)) == pytest.approx(33.0)
    assert p.from_u(10.0) == 40.0  # clipped to the bound
    assert Parameter("friction.coulomb", 0.0, 1.0, 5.0, 0.1).start == 1.0  # start clipped
    with pytest.raises(DiagnosisOptionError, match="low < high"):
        Parameter("friction.coulomb", 1.0, 0.0, 0.5, 0.1)
    with pytest.raises(DiagnosisOptionError, match="log scale"):
        Parameter("friction.coulomb", 0.0, 1.0, 0.5, 0.1, log=True)


@pytest.mark.parametrize(("c", "s"), [(0.03, -0.04), (-0.05, 0.0), (-0.01, -0.02)])
def test_periodic_pseudo_keys_become_amplitude_and_phase(c: float, s: float) -> None:
    """What the fit uses (axis_with): A·cos φ and A·sin φ -> amplitude and phase, against
    the complex number c + i·s (numpy's abs and angle), in every quadrant."""
    base = truth_axis().with_values(
        {"disturbance.periodic_amplitude": 0.0, "disturbance.periodic_period": 0.01}
    )
    axis = axis_with(base, {PERIODIC_COS: c, PERIODIC_SIN: s})
    assert axis.disturbance.periodic_amplitude == pytest.approx(abs(complex(c, s)))
    assert axis.disturbance.periodic_phase == pytest.approx(float(np.angle(complex(c, s))))
    # the torque the kernel gets, A·sin(2πx/p + φ), is c·sin(2πx/p) + s·cos(2πx/p)
    x = np.linspace(0.0, 0.02, 7)
    w = 2 * math.pi * x / 0.01
    a, phi = axis.disturbance.periodic_amplitude, axis.disturbance.periodic_phase
    np.testing.assert_allclose(a * np.sin(w + phi), c * np.sin(w) + s * np.cos(w), atol=1e-15)


@pytest.mark.parametrize("factor", [0.6, 1.6])
def test_refit_recovers_parameters_from_a_bad_start(factor: float) -> None:
    """Noise-free recording of the truth; the nominal is off by -40 % / +60 % in mass and
    friction: the bounded multi-start fit lands on the truth (robust to the start)."""
    truth = truth_axis()
    rec = recording(truth)
    nominal = truth.with_values(
        {
            "mechanics.load_mass": 25.0 * factor,
            "friction.coulomb": 0.08 * factor,
            "friction.viscous": 0.4 / factor,
        }
    )
    obj = objective(nominal, rec)
    scales = data_scales(obj.inp)
    keys = ("mechanics.load_mass", "friction.coulomb", "friction.viscous")
    params = tuple(
        parameter_for(k, float(nominal.value(k)), scales, nominal, nominal) for k in keys
    )
    spec = FitSpec(nominal, params, n_global=6)
    result = fit(spec, obj, max_nfev=30, n_starts=2)
    assert result.values["mechanics.load_mass"] == pytest.approx(25.0, rel=0.02)
    assert result.values["friction.coulomb"] == pytest.approx(0.08, rel=0.05)
    assert result.values["friction.viscous"] == pytest.approx(0.4, rel=0.05)
    assert result.cost < 1e-4


def test_discrete_delay_is_profiled() -> None:
    """A dead time of 3 speed cycles in the truth is found on the grid of whole cycles."""
    truth = truth_axis().with_values({"control.delay": 3 * 0.000125})
    rec = recording(truth, seconds=3.0)
    base = truth_axis()
    obj = objective(base, rec)
    grid = tuple(n * 0.000125 for n in (1, 2, 3, 4, 6, 8))
    spec = FitSpec(base, (), discrete=DiscreteParameter("control.delay", grid, grid[0]))
    result = fit(spec, obj)
    assert result.values["control.delay"] == pytest.approx(3 * 0.000125)
    assert result.cost < 1e-12
