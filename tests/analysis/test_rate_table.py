from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.rate_table import fit_rate_table, reference_rate_from_encoder

RATES = np.array([-250.0, -200, -100, -50, -10, 0, 10, 50, 100, 200, 250])
FS_DPS = 250.0


def _plateaus(
    rng: np.random.Generator, k: float = 1.0567, b: float = 8.6, k2: float = 0.0,
    asym: float = 0.0, u_out: float = 0.003, u_in: float = 2e-4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    w_true = RATES
    scale = k * (1.0 + 0.5 * asym * np.sign(w_true))
    y = scale * w_true + b + k2 * w_true**2 + u_out * rng.standard_normal(w_true.size)
    w_meas = w_true + u_in * rng.standard_normal(w_true.size)  # encoder reference with error
    return w_meas, np.full(w_true.size, u_in), y, np.full(w_true.size, u_out)


def test_recovers_scale_and_bias_of_a_linear_part() -> None:
    fit = fit_rate_table(*_plateaus(np.random.default_rng(0)), full_scale_dps=FS_DPS)
    assert abs(fit.scale - 1.0567) <= 3 * fit.u_scale
    assert abs(fit.bias_dps - 8.6) <= 3 * fit.u_bias_dps
    assert fit.u_scale < 2e-5
    assert fit.scale_correction == pytest.approx(1 / fit.scale)


def test_k2_intervals_of_scale_and_bias_cover_93_to_97_percent() -> None:
    rng = np.random.default_rng(1)
    trials = 1000
    hits_k = hits_b = 0
    for _ in range(trials):
        fit = fit_rate_table(*_plateaus(rng, u_in=0.004), full_scale_dps=FS_DPS)
        hits_k += abs(fit.scale - 1.0567) <= fit.u_scale_k2
        hits_b += abs(fit.bias_dps - 8.6) <= fit.u_bias_dps_k2
    assert 0.93 <= hits_k / trials <= 0.97, hits_k / trials
    assert 0.93 <= hits_b / trials <= 0.97, hits_b / trials


def _noise_free_nonlinearity(k: float, b: float, k2: float) -> float:
    """IEEE 1431 definition applied to the exact curve at the same rates."""
    y = k * RATES + b + k2 * RATES**2
    p = np.polyfit(RATES, y, 1)
    return float(np.max(np.abs(y - np.polyval(p, RATES))) / (p[0] * FS_DPS) * 100.0)


def test_quadratic_term_gives_nonlinearity_within_its_uncertainty() -> None:
    """Nonlinearity is a largest-residual statistic, so it sits a little high; its k=2
    interval still holds the noise-free value in >= 90 % of records, and k2 in 93-97 %."""
    k2 = 5e-6  # per deg/s, the docs/interfaces.md example effect: 0.08 % FS on this rate set
    truth = _noise_free_nonlinearity(1.0567, 8.6, k2)
    assert truth > 0.05
    rng = np.random.default_rng(2)
    trials, hits_nl, hits_k2 = 400, 0, 0
    for _ in range(trials):
        fit = fit_rate_table(*_plateaus(rng, k2=k2), full_scale_dps=FS_DPS)
        hits_nl += abs(fit.nonlinearity_pct_fs - truth) <= 2 * fit.u_nonlinearity_pct_fs
        hits_k2 += abs(fit.k2_per_dps - k2) <= 2 * fit.u_k2_per_dps
        assert fit.chi2_per_dof > 10  # the straight line visibly fails
    assert hits_nl / trials >= 0.90, hits_nl / trials
    assert 0.92 <= hits_k2 / trials <= 0.98, hits_k2 / trials  # 400 trials: +/- 1.1 % sd


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_known_asymmetry_is_recovered_within_its_uncertainty(seed: int) -> None:
    asym = 500e-6
    fit = fit_rate_table(*_plateaus(np.random.default_rng(seed), asym=asym), full_scale_dps=FS_DPS)
    assert abs(fit.asymmetry_ppm - 500.0) <= 2 * fit.u_asymmetry_ppm
    assert fit.u_asymmetry_ppm < 100.0
    assert fit.scale_positive > fit.scale_negative


def test_symmetric_linear_part_shows_no_asymmetry_or_nonlinearity() -> None:
    fit = fit_rate_table(*_plateaus(np.random.default_rng(8)), full_scale_dps=FS_DPS)
    assert abs(fit.asymmetry_ppm) <= 3 * fit.u_asymmetry_ppm
    assert fit.nonlinearity_pct_fs < 0.005


def test_one_direction_rate_set_is_refused() -> None:
    w = np.array([10.0, 50.0, 100.0])
    with pytest.raises(AnalysisError, match="both directions"):
        fit_rate_table(w, np.full(3, 1e-3), w, np.full(3, 1e-3), FS_DPS)


def test_reference_rate_from_encoder_unwraps_counts() -> None:
    cpr = 1 << 20
    counts = np.array([2**32 - 1000, 2**32 - 10, 5000], dtype=np.int64)  # wraps once
    ref = reference_rate_from_encoder(counts, [0.0, 0.5, 2.0], cpr)
    assert ref.angle_deg == pytest.approx(6000 * 360 / cpr)
    assert ref.rate_dps == pytest.approx(ref.angle_deg / 2.0)


def test_reference_rate_uncertainty_matches_quantisation_and_time_stamp_scatter() -> None:
    rng = np.random.default_rng(9)
    cpr, rate, res = 4096, 100.0, 1e-3
    errs, us = [], []
    for _ in range(4000):
        t0 = rng.uniform(0, 10)
        t1 = t0 + rng.uniform(1.9, 2.1)  # plateau ends fall anywhere on the clock grid
        a0 = rng.uniform(0, 360)
        counts = np.floor(np.array([a0, a0 + rate * (t1 - t0)]) / 360 * cpr)
        stamps = np.round(np.array([t0, t1]) / res) * res  # controller stamps, 1 ms
        ref = reference_rate_from_encoder(counts, stamps, cpr, res)
        errs.append(ref.rate_dps - rate)
        us.append(ref.u_rate_dps)
    assert abs(np.mean(errs)) < 3 * np.std(errs) / np.sqrt(len(errs))
    assert np.std(errs) == pytest.approx(np.sqrt(np.mean(np.square(us))), rel=0.1)
