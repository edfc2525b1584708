"""Bridge parameters: ranges, the regulator's rules (section VII, eq. 14) and abort codes."""

from __future__ import annotations

import math

import pytest

from bridge.errors import BridgeError, ParameterError, SdoAbort
from bridge.params import BOUNDS, LOCKED, MAX_SPEED_RAD_S, BridgeParams, check_field
from bridge.scaling import INT32_MAX, MOTOR_INCREMENTS_PER_RAD
from regulator import RegulatorConfig, max_cycle_s
from virtual_bus.formats.axis import load_axis

AXIS = load_axis("config/paper_axis.toml")


@pytest.fixture
def params() -> BridgeParams:
    return BridgeParams.for_axis(AXIS)


def test_defaults_come_from_the_axis_file(params: BridgeParams) -> None:
    assert params.kv_per_s == AXIS.control.kv
    assert params.transmission_ratio == AXIS.transmission_ratio
    assert params.cycle_s == AXIS.control.position_cycle
    assert params.regulator_config() == RegulatorConfig(kv=25.0, cycle_s=0.001)
    # section II.B: the measuring systems agree within about 0.5 mm
    assert params.discrepancy_limit == pytest.approx(0.5e-3)


@pytest.mark.parametrize(
    ("field", "value", "code"),
    [
        ("kv_per_s", 0.0, SdoAbort.TOO_LOW),
        ("kv_per_s", -3.0, SdoAbort.TOO_LOW),
        ("kv_per_s", 5000.0, SdoAbort.TOO_HIGH),
        ("kv_per_s", math.nan, SdoAbort.VALUE_RANGE),
        ("kv_per_s", math.inf, SdoAbort.VALUE_RANGE),
        ("beta_t_rad_s", 0.0, SdoAbort.TOO_LOW),
        ("n", 0, SdoAbort.TOO_LOW),
        ("n", 65, SdoAbort.TOO_HIGH),
        ("n", 2.5, SdoAbort.VALUE_RANGE),
        ("tf_s", -1.0, SdoAbort.TOO_LOW),
        ("cycle_s", 1e-5, SdoAbort.TOO_LOW),
        ("speed_limit_rad_s", MAX_SPEED_RAD_S * 1.01, SdoAbort.TOO_HIGH),
        ("pdo_loss_tolerance", 256, SdoAbort.TOO_HIGH),
        ("heartbeat_consumer_ms", -1, SdoAbort.TOO_LOW),
        ("regulator_enabled", 2, SdoAbort.VALUE_RANGE),
        ("accel", -1.0, SdoAbort.TOO_LOW),
    ],
)
def test_out_of_range_values_get_their_abort_code(
    params: BridgeParams, field: str, value: object, code: SdoAbort
) -> None:
    with pytest.raises(ParameterError) as info:
        params.with_value(field, value)
    assert info.value.abort_code is code
    assert info.value.field == field
    assert field in str(info.value)
    assert isinstance(info.value, BridgeError) and isinstance(info.value, ValueError)


def test_the_sampling_rule_of_section_vii_makes_kv_too_high(params: BridgeParams) -> None:
    # cycle < 1 / (2 (n+1) kv): with 1 ms and n = 4, kv must stay below 100 1/s
    limit_kv = 1.0 / (2 * 5 * params.cycle_s)
    ok = params.with_value("kv_per_s", limit_kv * 0.99)
    assert ok.kv_per_s == pytest.approx(limit_kv * 0.99)
    with pytest.raises(ParameterError) as info:
        params.with_value("kv_per_s", limit_kv * 1.01)
    assert info.value.abort_code is SdoAbort.TOO_HIGH
    with pytest.raises(ParameterError) as info:
        params.with_value("n", 20)  # 1 ms >= 1/(2*21*25) = 0.95 ms
    assert info.value.abort_code is SdoAbort.TOO_HIGH
    assert max_cycle_s(25.0, 20) < params.cycle_s
    with pytest.raises(ParameterError) as info:
        params.with_value("cycle_s", 0.0045)
    assert info.value.abort_code is SdoAbort.TOO_HIGH


def test_eq14_makes_a_short_tv_too_low(params: BridgeParams) -> None:
    # eq. 14: T_v >= 5/f with f = kv/4 -> 20/kv = 0.8 s at kv = 25
    assert params.with_value("tv_s", 0.8).tv_s == 0.8
    with pytest.raises(ParameterError) as info:
        params.with_value("tv_s", 0.5)
    assert info.value.abort_code is SdoAbort.TOO_LOW
    # a larger kv shortens the bound; tv fixed at 0.8 s stays valid when kv grows
    longer = params.with_value("tv_s", 0.8)
    assert longer.with_value("kv_per_s", 30.0).kv_per_s == 30.0
    # ... but kv shrinking below 20/0.8 = 25 is refused (tv now too short) as "too low"
    with pytest.raises(ParameterError) as info:
        longer.with_value("kv_per_s", 20.0)
    assert info.value.abort_code is SdoAbort.TOO_LOW


def test_feed_must_fit_under_the_speed_limit(params: BridgeParams) -> None:
    top = params.speed_limit_rad_s / params.transmission_ratio
    assert params.with_value("feed", top * 0.99).feed == pytest.approx(top * 0.99)
    with pytest.raises(ParameterError) as info:
        params.with_value("feed", top * 1.01)
    assert info.value.abort_code is SdoAbort.TOO_HIGH
    with pytest.raises(ParameterError) as info:
        params.with_value("speed_limit_rad_s", params.feed * params.transmission_ratio * 0.9)
    assert info.value.abort_code is SdoAbort.TOO_LOW


@pytest.mark.parametrize("field", sorted(LOCKED))
def test_locked_fields_refuse_changes_while_enabled(params: BridgeParams, field: str) -> None:
    value = getattr(params, field)
    with pytest.raises(ParameterError) as info:
        params.with_value(field, value, axis_enabled=True)
    assert info.value.abort_code is SdoAbort.DEVICE_STATE


def test_limits_may_change_while_enabled(params: BridgeParams) -> None:
    new = params.with_value("following_error_limit", 0.002, axis_enabled=True)
    assert new.following_error_limit == 0.002
    assert params.following_error_limit != 0.002  # the original is unchanged (frozen)


def test_speed_limit_fits_the_target_velocity_object() -> None:
    assert round(MAX_SPEED_RAD_S * MOTOR_INCREMENTS_PER_RAD) <= INT32_MAX


def test_every_bound_is_checked() -> None:
    for field, bound in BOUNDS.items():
        high = bound.high + (1 if isinstance(bound.high, int) else abs(bound.high) * 0.01 + 1e-9)
        with pytest.raises(ParameterError):
            check_field(field, high)


def test_construction_errors_name_field_and_code() -> None:
    with pytest.raises(ParameterError) as info:
        BridgeParams(kv_per_s=25.0, transmission_ratio=100.0, cycle_s=0.01)
    assert info.value.field == "cycle_s"
    assert info.value.abort_code is SdoAbort.TOO_HIGH
