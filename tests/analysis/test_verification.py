from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.temp_supply_fit import FirstOrderCoefficients
from procedures.analysis.verification import correct_rate, verify_correction

COEFFS = FirstOrderCoefficients(
    bias_dps=8.6, bias_temp_coeff_dps_per_c=0.008, bias_supply_coeff_dps_per_v=0.05,
    scale=1.0567, scale_temp_coeff_per_c=200e-6, scale_supply_coeff_per_v=1e-3,
)


def test_correction_inverts_the_first_order_error_model() -> None:
    rng = np.random.default_rng(0)
    w = rng.uniform(-250, 250, 500)
    temp_c = rng.uniform(20, 65, 500)
    supply_v = rng.uniform(4.7, 5.3, 500)
    dt, dv = temp_c - 25.0, supply_v - 5.0
    raw = 1.0567 * (1 + 200e-6 * dt + 1e-3 * dv) * w + 8.6 + 0.008 * dt + 0.05 * dv
    assert np.max(np.abs(correct_rate(raw, temp_c, supply_v, COEFFS) - w)) < 1e-10
    # applying the raw output uncorrected would be off by the full 5.7 % scale error
    assert np.max(np.abs(raw - w)) > 10.0


def test_residual_errors_in_percent_fs_and_ppm_of_reading() -> None:
    ref = np.array([-200.0, 0.0, 100.0])
    corrected = ref + np.array([0.05, 0.02, -0.01])
    res = verify_correction(ref, np.full(3, 1e-3), corrected, np.full(3, 2e-3), 250.0)
    pct = [p.error_pct_fs for p in res.points]
    assert pct == pytest.approx([0.02, 0.008, -0.004])
    ppm = [p.error_ppm_of_reading for p in res.points]
    assert ppm[0] == pytest.approx(250.0) and ppm[1] is None and ppm[2] == pytest.approx(-100.0)
    assert res.max_abs_error_pct_fs == pytest.approx(0.02)
    assert res.max_abs_error_ppm_of_reading == pytest.approx(250.0)
    assert res.points[0].u_error_dps == pytest.approx(np.hypot(1e-3, 2e-3))
    assert res.within(0.03) and not res.within(0.01)


def test_a_stale_coefficient_shows_up_as_error_at_verification() -> None:
    """Verify at 60 C with coefficients that lack the temperature terms: error appears."""
    ref = np.array([-250.0, -100.0, 100.0, 250.0])
    raw = 1.0567 * (1 + 200e-6 * 35) * ref + 8.6 + 0.008 * 35
    stale = FirstOrderCoefficients(8.6, 0.0, 0.05, 1.0567, 0.0, 1e-3)
    bad = verify_correction(ref, np.full(4, 1e-3), correct_rate(raw, 60.0, 5.0, stale),
                            np.full(4, 1e-3), 250.0)
    good = verify_correction(ref, np.full(4, 1e-3), correct_rate(raw, 60.0, 5.0, COEFFS),
                             np.full(4, 1e-3), 250.0)
    assert bad.max_abs_error_pct_fs > 0.5 and good.max_abs_error_pct_fs < 1e-8


def test_coefficient_uncertainty_propagates_to_the_corrected_rate() -> None:
    """MC: refit from noisy conditions many times; the scatter of the corrected rate at
    one (rate, T, V) point matches the propagated uncertainty."""
    from procedures.analysis.temp_supply_fit import ConditionMeasurement, fit_temp_supply
    from procedures.analysis.verification import correction_uncertainty_dps

    rng = np.random.default_rng(1)
    design = [(25.0, 4.75), (25.0, 5.25), (60.0, 4.75), (60.0, 5.25)]
    w_true, temp_c, supply_v = 200.0, 40.0, 5.1
    raw = float(COEFFS.scale_at(temp_c, supply_v)) * w_true + float(COEFFS.bias_at(temp_c,
                                                                                   supply_v))
    got, us = [], []
    for _ in range(1500):
        conds = [
            ConditionMeasurement(
                tc, v, float(COEFFS.bias_at(tc, v)) + 0.002 * rng.standard_normal(), 0.002,
                float(COEFFS.scale_at(tc, v)) + 3e-5 * rng.standard_normal(), 3e-5)
            for tc, v in design
        ]
        fit = fit_temp_supply(conds)
        got.append(float(correct_rate(raw, temp_c, supply_v, fit.coefficients)))
        us.append(float(correction_uncertainty_dps(fit, w_true, temp_c, supply_v)))
    assert np.std(got) == pytest.approx(np.mean(us), rel=0.1)
    assert abs(np.mean(got) - w_true) < 4 * np.std(got) / np.sqrt(len(got))
