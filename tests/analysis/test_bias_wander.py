"""The bias-wander covariance of window means (procedures/analysis/bias_wander.py) against a
Monte-Carlo simulation of the same Gauss-Markov terms, and its scaling with the bias
instability: windows close in time share most of it, windows far apart almost none."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.bias_wander import (
    WANDER_TAUS_S,
    term_sigma_dps,
    window_mean_covariance,
)

BI_DPS = 15.0 / 3600


def _simulate(starts: np.ndarray, ends: np.ndarray, runs: int, dt_s: float = 0.1) -> np.ndarray:
    """Window means of `runs` realisations of the GM sum (exact discretisation)."""
    rng = np.random.default_rng(5)
    n = int(np.ceil(ends.max() / dt_s))
    t = np.arange(n) * dt_s
    sigma = term_sigma_dps(BI_DPS)
    total = np.zeros((runs, n))
    for tau in WANDER_TAUS_S:
        a = np.exp(-dt_s / tau)
        x = rng.normal(0.0, sigma, runs)
        e = rng.normal(0.0, sigma * np.sqrt(1 - a * a), (runs, n))
        for k in range(n):
            x = a * x + e[:, k]
            total[:, k] += x
    return np.column_stack([total[:, (t >= s) & (t < f)].mean(axis=1)
                            for s, f in zip(starts, ends, strict=True)])


def test_covariance_matches_a_simulation_of_the_wander() -> None:
    starts = np.array([0.0, 12.0, 25.0, 200.0])
    ends = starts + 10.0
    cov = window_mean_covariance(starts, ends, BI_DPS)
    means = _simulate(starts, ends, runs=3000)
    empirical = np.cov(means, rowvar=False)
    # 3000 runs: a (co)variance is good to about 2.6 % of the product of the SDs (1 sigma)
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.all(np.abs(empirical - cov) < 0.12 * scale), (empirical / scale, cov / scale)


def test_windows_far_apart_share_little_and_it_scales_with_bias_instability() -> None:
    starts = np.array([0.0, 15.0, 3000.0])
    cov = window_mean_covariance(starts, starts + 10.0, BI_DPS)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert corr[0, 1] > 0.5 and corr[0, 2] < 1e-3
    double = window_mean_covariance(starts, starts + 10.0, 2 * BI_DPS)
    assert np.allclose(double, 4 * cov)


def test_random_walk_covariance_matches_a_simulation() -> None:
    """A rate random walk K from the first window's start (where the simulation's walk is 0)."""
    k = 4.0 / 3600 / 60  # 4 deg/h/sqrt(h) in deg/s/sqrt(s)
    starts = np.array([0.0, 30.0, 600.0])
    ends = starts + 10.0
    cov = window_mean_covariance(starts, ends, 0.0, k)
    rng = np.random.default_rng(11)
    dt_s = 0.5
    t = np.arange(int(ends.max() / dt_s)) * dt_s
    walk = np.cumsum(rng.normal(0.0, k * np.sqrt(dt_s), (4000, t.size)), axis=1)
    means = np.column_stack([walk[:, (t >= s) & (t < f)].mean(axis=1)
                             for s, f in zip(starts, ends, strict=True)])
    empirical = np.cov(means, rowvar=False)
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.all(np.abs(empirical - cov) < 0.12 * scale), (empirical / scale, cov / scale)


def test_the_bias_step_takes_its_windows_wander_from_the_model_unless_given_a_factor() -> None:
    """A condition's bias carries the wander of its window's mean: about 1.19 x BI for 30 s
    under the model (longer windows average more of it away); `wander_factor` x BI where
    the procedure gives one."""
    from procedures.steps.bias import Bias, BiasSettings

    b_dps = 15.0 / 3600.0
    model = Bias(BiasSettings())
    assert model._wander_dps(100.0, 130.0, b_dps, 0.0) == pytest.approx(1.19 * b_dps, rel=0.01)
    assert model._wander_dps(100.0, 160.0, b_dps, 0.0) < model._wander_dps(100.0, 130.0, b_dps, 0.0)
    given = Bias(BiasSettings(wander_factor=1.5))
    assert given._wander_dps(100.0, 130.0, b_dps, 0.0) == pytest.approx(1.5 * b_dps)
