"""Bias wander shared between windows: the covariance of window means under bias instability.

A gyro's bias instability (the flat floor of its Allan deviation, 0.664 x BI) is flicker
noise; over the time scales a calibration spans it is well described by a sum of first-order
Gauss-Markov processes with correlation times one decade apart (here 3, 30 and 300 s: from a
window's length to a condition's), of one common variance chosen so that their summed Allan
deviation peaks at 0.664 x BI. Two window means close in time then share most of the slow
terms and little of the fast one; windows far apart (other conditions) share almost none.
A rate random walk (the Allan deviation's +1/2 slope, K in deg/s/sqrt(s)) adds a drift that
windows far apart do not share: counted from the first window, Cov = K^2 min(t_i, t_j) for
window means (t the window's middle; a window's own: its start + T/3). The fitted bias absorbs
the choice of origin.

A fit that treats short windows as independent would average the wander away and understate
the bias and its temperature and supply coefficients.

    cov = window_mean_covariance(start_s, end_s, bias_instability_dps, rrw_dps_per_sqrt_s)
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

WANDER_TAUS_S = (3.0, 30.0, 300.0)
ALLAN_FLOOR_PER_BI = 0.664


def _gm_avar(tau_s: FloatArray, corr_s: float) -> FloatArray:
    """Allan variance of a unit-variance first-order Gauss-Markov process."""
    x = tau_s / corr_s
    bracket = 1.0 - (3.0 - 4.0 * np.exp(-x) + np.exp(-2.0 * x)) / (2.0 * x)
    return np.asarray(2.0 * corr_s / tau_s * bracket, dtype=np.float64)


@lru_cache(maxsize=1)
def _unit_peak_adev() -> float:
    tau = np.logspace(-1, 4, 400)
    return math.sqrt(float(np.max(sum(_gm_avar(tau, c) for c in WANDER_TAUS_S))))


def term_sigma_dps(bias_instability_dps: float) -> float:
    """The common standard deviation of each Gauss-Markov term for a bias instability."""
    return ALLAN_FLOOR_PER_BI * bias_instability_dps / _unit_peak_adev()


def window_mean_covariance(
    start_s: FloatArray, end_s: FloatArray, bias_instability_dps: float,
    rrw_dps_per_sqrt_s: float = 0.0,
) -> FloatArray:
    """Covariance (deg/s)^2 of the means of windows [start, end] (one time base, seconds)
    under the bias wander: exact for first-order Gauss-Markov terms, for windows that do
    not overlap (and on the diagonal, the variance of each window's mean)."""
    t0 = np.asarray(start_s, dtype=np.float64)
    t1 = np.asarray(end_s, dtype=np.float64)
    length = np.maximum(t1 - t0, 1e-9)
    sigma2 = term_sigma_dps(bias_instability_dps) ** 2
    out = np.zeros((t0.size, t0.size))
    for tau in WANDER_TAUS_S:
        # each window's mean responds to the process through (tau/T)(1 - exp(-T/tau))
        gain = tau / length * (1.0 - np.exp(-length / tau))
        gap = np.maximum(t0[None, :] - t1[:, None], t0[:, None] - t1[None, :])
        across = sigma2 * np.outer(gain, gain) * np.exp(-np.maximum(gap, 0.0) / tau)
        x = length / tau
        own = sigma2 * 2.0 / x**2 * (x - 1.0 + np.exp(-x))
        np.fill_diagonal(across, own)
        out += across
    return out + _random_walk_covariance(t0, t1, rrw_dps_per_sqrt_s)


def _random_walk_covariance(t0: FloatArray, t1: FloatArray, k: float) -> FloatArray:
    """Covariance of window means under a rate random walk K, from the first window's start
    (windows that do not overlap)."""
    if k <= 0 or t0.size == 0:
        return np.zeros((t0.size, t0.size))
    origin = float(np.min(t0))
    mid = 0.5 * (t0 + t1) - origin
    cov = k * k * np.minimum(mid[:, None], mid[None, :])
    np.fill_diagonal(cov, k * k * (t0 - origin + (t1 - t0) / 3.0))
    return np.asarray(cov, dtype=np.float64)
