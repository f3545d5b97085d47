"""Mean of a static (or constant-rate) window with an uncertainty that respects correlated noise.

Gyro noise is not white over long windows, so sigma / sqrt(N) understates the uncertainty of a
mean. The standard uncertainty of a window mean here is the Allan deviation at the window's
own length T, read from the noise model fitted to the window's Allan deviation (a record of
length T only measures taus up to T/2, so the model carries it to T). For white noise this is
exactly sigma / sqrt(N). A noise model measured on a longer record (e.g. the part's own Allan
run) can be passed in instead, which is better for short windows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from procedures.analysis._checks import finite_1d, positive
from procedures.analysis.allan import (
    FLICKER_AVAR_FACTOR,
    MIN_SAMPLES,
    NoiseModel,
    fit_noise_model,
    overlapping_adev,
)
from procedures.analysis.errors import AnalysisError


@dataclass(frozen=True)
class WindowMean:
    """Mean output over a window with its standard (k=1) uncertainty."""

    mean_dps: float
    u_mean_dps: float  # k=1: Allan deviation at the window length
    duration_s: float
    n_samples: int
    noise: NoiseModel  # the model the uncertainty came from
    naive_u_dps: float  # sigma / sqrt(N), for comparison only

    @property
    def u_mean_dps_k2(self) -> float:
        return 2.0 * self.u_mean_dps


@dataclass(frozen=True)
class BiasEstimate:
    """Bias from a static window; the correction is its negative (METHOD.md convention)."""

    bias_dps: float
    u_bias_dps: float  # k=1
    duration_s: float
    n_samples: int
    noise: NoiseModel

    @property
    def bias_correction_dps(self) -> float:
        return -self.bias_dps

    @property
    def u_bias_dps_k2(self) -> float:
        return 2.0 * self.u_bias_dps

    def averaging_time_s(self, bias_accuracy_dps: float, k: float = 2.0) -> float:
        """Averaging time for a bias known to `bias_accuracy_dps` at coverage factor k."""
        return required_averaging_time_s(self.noise, bias_accuracy_dps, k)


def window_mean(
    rate_dps: ArrayLike, sample_rate_hz: float, noise: NoiseModel | None = None
) -> WindowMean:
    """Mean of a window of samples; uncertainty = Allan deviation at the window length."""
    rate = finite_1d(rate_dps, "rate_dps", MIN_SAMPLES)
    fs = positive(sample_rate_hz, "sample_rate_hz")
    if noise is None and np.all(rate == rate[0]):
        raise AnalysisError(
            f"rate_dps is constant ({float(rate[0])!r}) over all {rate.size} samples, so its "
            "uncertainty cannot be judged: the output is stuck or its resolution is coarser "
            "than its noise; check the part and the fixture"
        )
    duration_s = rate.size / fs
    if noise is None:
        noise = fit_noise_model(overlapping_adev(rate, fs, "octave")).model
    u = float(np.sqrt(noise.avar_dps2(duration_s)))
    naive = float(np.std(rate, ddof=1) / math.sqrt(rate.size))
    return WindowMean(
        mean_dps=float(rate.mean()),
        u_mean_dps=u,
        duration_s=duration_s,
        n_samples=int(rate.size),
        noise=noise,
        naive_u_dps=naive,
    )


def estimate_bias(
    rate_dps: ArrayLike, sample_rate_hz: float, noise: NoiseModel | None = None
) -> BiasEstimate:
    """Bias of a gyro at rest from a window of its output."""
    wm = window_mean(rate_dps, sample_rate_hz, noise)
    return BiasEstimate(
        bias_dps=wm.mean_dps,
        u_bias_dps=wm.u_mean_dps,
        duration_s=wm.duration_s,
        n_samples=wm.n_samples,
        noise=wm.noise,
    )


def required_averaging_time_s(noise: NoiseModel, bias_accuracy_dps: float, k: float = 2.0) -> float:
    """Shortest averaging time whose k * ADEV reaches `bias_accuracy_dps`.

    Returns math.inf when the flat part or the rate random walk keeps the deviation above
    the request at every tau (averaging longer cannot help; the message of the caller should
    say so).
    """
    target = positive(bias_accuracy_dps, "bias_accuracy_dps") / positive(k, "k")
    n2 = noise.arw_deg_per_sqrt_s**2
    floor = FLICKER_AVAR_FACTOR * noise.bias_instability_dps**2
    k2 = noise.rrw_dps_per_sqrt_s**2 / 3.0
    rhs = target**2 - floor
    if rhs <= 0.0:
        return math.inf
    if k2 == 0.0:
        if n2 == 0.0:
            return 0.0
        return n2 / rhs
    # N^2/tau + k2 tau = rhs: the smaller root is the first tau reaching the target.
    disc = rhs * rhs - 4.0 * k2 * n2
    if disc < 0.0:
        return math.inf
    return (rhs - math.sqrt(disc)) / (2.0 * k2)


def require_averaging_time_s(noise: NoiseModel, bias_accuracy_dps: float, k: float = 2.0) -> float:
    """As required_averaging_time_s, but raises if no averaging time reaches the accuracy."""
    t = required_averaging_time_s(noise, bias_accuracy_dps, k)
    if math.isinf(t):
        best = float(np.min(noise.adev_dps(np.logspace(-2, 5, 300)))) * k
        raise AnalysisError(
            f"no averaging time gives a bias accuracy of {bias_accuracy_dps:g} deg/s (k={k:g}); "
            f"the best this part's noise allows is about {best:.3g} deg/s: relax the request"
        )
    return t
