from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_supply_fit import (
    COEFFICIENT_NAMES,
    ConditionMeasurement,
    fit_temp_supply,
)
from procedures.runtime.record import Calibration

TRUTH = {
    "bias_dps": 8.6,
    "bias_temp_coeff_dps_per_c": 0.008,
    "bias_supply_coeff_dps_per_v": 0.05,
    "scale": 1.0567,
    "scale_temp_coeff_per_c": 200e-6,
    "scale_supply_coeff_per_v": 1e-3,
}
DESIGN = [(25.0, 4.75), (25.0, 5.25), (60.0, 4.75), (60.0, 5.25)]


def _conditions(
    rng: np.random.Generator | None, u_bias: float = 0.002, u_scale: float = 3e-5,
    interaction_dps: float = 0.0,
) -> list[ConditionMeasurement]:
    out = []
    for temp_c, supply_v in DESIGN:
        dt, dv = temp_c - 25.0, supply_v - 5.0
        bias = (TRUTH["bias_dps"] + TRUTH["bias_temp_coeff_dps_per_c"] * dt
                + TRUTH["bias_supply_coeff_dps_per_v"] * dv + interaction_dps * dt * dv)
        scale = TRUTH["scale"] * (1 + TRUTH["scale_temp_coeff_per_c"] * dt
                                  + TRUTH["scale_supply_coeff_per_v"] * dv)
        if rng is not None:
            # per-condition uncertainties differ, as they do on the station
            ub, us = u_bias * rng.uniform(0.5, 2.0), u_scale * rng.uniform(0.5, 2.0)
            bias += ub * rng.standard_normal()
            scale += us * rng.standard_normal()
        else:
            ub, us = u_bias, u_scale
        out.append(ConditionMeasurement(temp_c, supply_v, bias, ub, scale, us))
    return out


def test_noise_free_conditions_give_the_coefficients_exactly() -> None:
    fit = fit_temp_supply(_conditions(None))
    for name, value in TRUTH.items():
        assert getattr(fit.coefficients, name) == pytest.approx(value, rel=1e-9, abs=1e-15)
    assert fit.interaction is not None
    assert abs(fit.interaction.bias_normalised) < 1e-6


def test_k2_intervals_of_every_coefficient_cover_93_to_97_percent() -> None:
    rng = np.random.default_rng(10)
    trials = 1000
    hits = dict.fromkeys(COEFFICIENT_NAMES, 0)
    z_inter = []
    for _ in range(trials):
        fit = fit_temp_supply(_conditions(rng))
        for name in COEFFICIENT_NAMES:
            hits[name] += abs(getattr(fit.coefficients, name) - TRUTH[name]) <= (
                fit.uncertainty_k2(name))
        z_inter.append(fit.interaction.bias_normalised)  # type: ignore[union-attr]
    for name, h in hits.items():
        assert 0.93 <= h / trials <= 0.97, (name, h / trials)
    # without a real interaction, the spare degree of freedom is standard normal
    assert 0.93 <= np.mean(np.abs(z_inter) <= 2.0) <= 0.97


def test_interaction_is_flagged_by_the_spare_degree_of_freedom() -> None:
    fit = fit_temp_supply(_conditions(np.random.default_rng(11), interaction_dps=0.004))
    check = fit.interaction
    assert check is not None
    assert abs(check.bias_normalised) > 3 and not check.consistent()
    assert check.bias_interaction_dps_per_c_v == pytest.approx(0.004, abs=3 * (
        check.u_bias_interaction_dps_per_c_v))
    assert check.bias_chi2 == pytest.approx(check.bias_normalised**2, rel=1e-6)


def test_reference_conditions_are_configurable() -> None:
    fit_a = fit_temp_supply(_conditions(None))
    fit_b = fit_temp_supply(_conditions(None), reference_temperature_c=40.0,
                            reference_supply_v=5.25)
    c_b = fit_b.coefficients
    assert c_b.bias_dps == pytest.approx(float(fit_a.coefficients.bias_at(40.0, 5.25)))
    assert c_b.scale == pytest.approx(float(fit_a.coefficients.scale_at(40.0, 5.25)))
    assert float(c_b.bias_at(25.0, 4.75)) == pytest.approx(float(
        fit_a.coefficients.bias_at(25.0, 4.75)))


def test_calibration_block_validates_against_the_record_contract() -> None:
    block = fit_temp_supply(_conditions(np.random.default_rng(12))).as_calibration_dict()
    cal = Calibration.model_validate(block)
    assert cal.scale.value == pytest.approx(1.0567, rel=1e-3)
    assert cal.bias_dps.uncertainty_k2 > 0
    assert cal.interaction_check is not None


def test_single_temperature_design_is_refused() -> None:
    conds = [ConditionMeasurement(25.0, v, 8.6, 0.01, 1.05, 1e-4) for v in (4.75, 5.0, 5.25)]
    with pytest.raises(AnalysisError, match="two temperatures"):
        fit_temp_supply(conds)


def test_too_few_conditions_are_refused() -> None:
    with pytest.raises(AnalysisError, match="at least three"):
        fit_temp_supply(_conditions(None)[:2])
