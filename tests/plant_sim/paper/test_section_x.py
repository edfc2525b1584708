"""The paper's section X and section VI claims, reproduced by the simulator."""

from __future__ import annotations

import pytest

from plant_sim.paper.outputs import LIMIT_CYCLE_VISCOUS, summarize
from plant_sim.paper.scenarios import run_section_x
from tests.paths import CONFIG
from virtual_bus.formats.axis import AxisConfig, load_axis

PAPER = CONFIG / "paper_axis.toml"


@pytest.fixture(scope="module")
def paper() -> AxisConfig:
    return load_axis(PAPER)


@pytest.fixture(scope="module")
def limit_cycle_axis(paper: AxisConfig) -> AxisConfig:
    return paper.with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})


def test_paper_values_give_no_sustained_limit_cycle(paper: AxisConfig) -> None:
    """Documented finding (docs/paper_reproduction.md): with τ_f = 1.2 sign(v) + 57.3 v the
    load's viscous friction damps the limit cycle out; the axis runs smoothly after 4 s."""
    s = summarize(run_section_x(paper, with_regulator=False), paper)
    assert s.dominant_frequency_hz is None
    assert s.p2p_following_error < 5e-6


@pytest.mark.parametrize("cycle", [0.001, 0.0025])
def test_regulator_suppresses_the_limit_cycle(limit_cycle_axis: AxisConfig, cycle: float) -> None:
    """Section X / Fig. 8 vs Fig. 9: without the regulator the axis oscillates for the rest of
    the motion, in the band of eq. 13; with it the post-disturbance peak-to-peak following
    error falls by at least 90 % and the standstill error returns to (near) zero."""
    axis = limit_cycle_axis.with_values({"control.position_cycle": cycle})
    ordinary = summarize(run_section_x(axis, with_regulator=False), axis)
    regulated = summarize(run_section_x(axis, with_regulator=True), axis)
    assert ordinary.dominant_frequency_hz is not None and ordinary.in_band
    assert ordinary.vibration_amplitude == pytest.approx(axis.mechanics.backlash / 2, rel=0.2)
    assert regulated.dominant_frequency_hz is None
    assert regulated.p2p_following_error <= 0.1 * ordinary.p2p_following_error
    assert regulated.min_lambda < 0.5  # the regulator did act
    assert regulated.final_standstill_error < 1e-6


def test_limit_cycle_frequency_scales_with_kv_not_backlash(limit_cycle_axis: AxisConfig) -> None:
    """Section VI / eq. 12: f ∝ k_v and independent of δ (a small part of the sweep command)."""

    def freq(kv: float, delta: float) -> float:
        axis = limit_cycle_axis.with_values({"control.kv": kv, "mechanics.backlash": delta})
        f = summarize(run_section_x(axis, with_regulator=False), axis).dominant_frequency_hz
        assert f is not None, (kv, delta)
        assert kv / 4 <= f <= kv
        return f

    f25 = freq(25.0, 1e-4)
    assert freq(50.0, 1e-4) / f25 == pytest.approx(2.0, rel=0.15)
    assert freq(25.0, 4e-4) == pytest.approx(f25, rel=0.15)


@pytest.mark.parametrize("backlash", [0.0, None])
def test_no_false_alarm_without_backlash(
    limit_cycle_axis: AxisConfig, backlash: float | None
) -> None:
    """Section X without free play (speed step, 20 N·m disturbance on and off, stop): nothing
    vibrates, so the detector must not fade the load sensor out: λ stays close to 1."""
    axis = limit_cycle_axis.with_values({"mechanics.backlash": backlash})
    trace = run_section_x(axis, with_regulator=True)
    assert trace["lambda"].min() > 0.9
    assert summarize(trace, axis).dominant_frequency_hz is None
