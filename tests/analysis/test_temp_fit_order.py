"""Temperature fit of order 1..3 against synthetic truth; order 1 is today's fit exactly."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_fit import fit_temperature
from procedures.analysis.temp_supply_fit import ConditionMeasurement, fit_temp_supply

TRUTH = {
    "bias_dps": 8.6,
    "bias_temp_coeff_dps_per_c": 0.008,
    "bias_temp_coeff2_dps_per_c2": -1.2e-4,
    "bias_temp_coeff3_dps_per_c3": 2.0e-6,
    "bias_supply_coeff_dps_per_v": 0.05,
    "scale": 1.0567,
    "scale_temp_coeff_per_c": 200e-6,
    "scale_temp_coeff2_per_c2": -3e-6,
    "scale_temp_coeff3_per_c3": 5e-8,
    "scale_supply_coeff_per_v": 1e-3,
}
TEMPS = (-20.0, 5.0, 25.0, 45.0, 70.0)
SUPPLIES = (4.75, 5.25)


def _truth(order: int) -> dict[str, float]:
    drop = {2: ("coeff3",), 1: ("coeff2", "coeff3")}.get(order, ())
    return {k: v for k, v in TRUTH.items() if not any(d in k for d in drop)}


def _conditions(
    order: int, rng: np.random.Generator | None, temps: tuple[float, ...] = TEMPS,
    u_bias: float = 0.002, u_scale: float = 3e-5,
) -> list[ConditionMeasurement]:
    t = _truth(order)
    out = []
    for temp_c in temps:
        for supply_v in SUPPLIES:
            dt, dv = temp_c - 25.0, supply_v - 5.0
            bias = t["bias_dps"] + t["bias_supply_coeff_dps_per_v"] * dv
            rel = 1 + t["scale_supply_coeff_per_v"] * dv
            for k, (bn, sn) in enumerate(
                [("bias_temp_coeff_dps_per_c", "scale_temp_coeff_per_c"),
                 ("bias_temp_coeff2_dps_per_c2", "scale_temp_coeff2_per_c2"),
                 ("bias_temp_coeff3_dps_per_c3", "scale_temp_coeff3_per_c3")], start=1):
                bias += t.get(bn, 0.0) * dt**k
                rel += t.get(sn, 0.0) * dt**k
            scale = t["scale"] * rel
            ub, us = u_bias, u_scale
            if rng is not None:
                ub, us = u_bias * rng.uniform(0.5, 2.0), u_scale * rng.uniform(0.5, 2.0)
                bias += ub * rng.standard_normal()
                scale += us * rng.standard_normal()
            out.append(ConditionMeasurement(temp_c, supply_v, bias, ub, scale, us))
    return out


@pytest.mark.parametrize("order", [1, 2, 3])
def test_noise_free_conditions_give_each_order_exactly(order: int) -> None:
    fit = fit_temperature(_conditions(order, None), order)
    assert fit.order == order
    for name, value in _truth(order).items():
        assert fit.value(name) == pytest.approx(value, rel=1e-7, abs=1e-14), name
    assert fit.bias_chi2 == pytest.approx(0.0, abs=1e-6)


def test_order_1_is_todays_fit_bit_for_bit() -> None:
    conds = _conditions(1, np.random.default_rng(3), temps=(25.0, 60.0))
    today = fit_temp_supply(conds)
    fit = fit_temperature(conds, 1)
    assert fit.as_calibration_dict() == today.as_calibration_dict()
    for name in today.as_calibration_dict():
        if isinstance(today.as_calibration_dict()[name], dict) and name != "interaction_check":
            assert fit.value(name) == getattr(today.coefficients, name)
            assert fit.uncertainty(name) == today.uncertainty(name)


@pytest.mark.parametrize("order", [2, 3])
def test_k2_intervals_cover_about_95_percent(order: int) -> None:
    rng = np.random.default_rng(20 + order)
    trials = 600
    names = list(_truth(order))
    hits = dict.fromkeys(names, 0)
    for _ in range(trials):
        fit = fit_temperature(_conditions(order, rng), order)
        for name in names:
            hits[name] += abs(fit.value(name) - TRUTH[name]) <= 2 * fit.uncertainty(name)
    for name in names:
        assert 0.92 <= hits[name] / trials <= 0.98, (name, hits[name] / trials)


def test_a_second_order_part_fitted_first_order_is_biased_and_second_order_is_not() -> None:
    conds = _conditions(2, None, temps=(-20.0, 25.0, 70.0))
    first, second = fit_temperature(conds, 1), fit_temperature(conds, 2)
    t = np.array([-20.0, 25.0, 70.0])
    truth = 8.6 + 0.008 * (t - 25) - 1.2e-4 * (t - 25) ** 2
    assert np.max(np.abs(second.bias_at(t, 5.0) - truth)) < 1e-9
    assert np.max(np.abs(first.bias_at(t, 5.0) - truth)) > 0.05
    # the curve's own uncertainty is smallest near the middle of the temperatures
    u = second.u_bias_at(np.array([-20.0, 25.0, 70.0]), 5.0)
    assert u[1] < u[0] and u[1] < u[2]


def test_second_order_calibration_block_holds_its_terms() -> None:
    fit = fit_temperature(_conditions(2, np.random.default_rng(1), temps=(-20, 25, 70)), 2)
    cal = fit.as_calibration_dict()
    assert cal["fit_order"] == 2
    assert "bias_temp_coeff2_dps_per_c2" in cal and "scale_temp_coeff2_per_c2" in cal
    assert "bias_temp_coeff3_dps_per_c3" not in cal
    entry = cal["bias_temp_coeff2_dps_per_c2"]
    assert isinstance(entry, dict) and entry["uncertainty_k2"] > 0


@pytest.mark.parametrize(("order", "temps"), [(2, (25.0, 60.0)), (3, (0.0, 25.0, 60.0))])
def test_too_few_temperatures_for_the_order_is_refused(order: int, temps: tuple) -> None:
    with pytest.raises(AnalysisError, match=f"order-{order} temperature fit needs {order + 1}"):
        fit_temperature(_conditions(1, None, temps=temps), order)


def test_unsupported_order_is_refused() -> None:
    with pytest.raises(AnalysisError, match="use 1, 2 or 3"):
        fit_temperature(_conditions(1, None), 4)
