"""Warm-up time: from power-on until the bias settles within a band of its final value.

The criterion is a fitted exponential, not the raw trace (a noisy trace crosses any band
back and forth). The output at rest from power-on is averaged in windows; the window means
are fitted, weighted by their own scatter, with

    b(t) = b_final + A exp(-t / tau)            t from power-on

and the warm-up time is when the fitted transient has decayed into the band:
|A| exp(-t / tau) <= band, so t_w = tau ln(|A| / band) (0 when |A| <= band already). Its
uncertainty is propagated from the fit's covariance of (A, tau), rescaled by the residual
scatter (bias instability makes the window means scatter more than their white noise).
A transient whose amplitude is not twice its uncertainty is 'not resolved' and the part is
settled from power-on (t_w = 0). A t_w beyond the record is an extrapolation: flagged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import curve_fit

from procedures.analysis._checks import finite_1d
from procedures.analysis.errors import AnalysisError

MIN_WINDOWS = 8
DEFAULT_WINDOWS = 60


@dataclass(frozen=True)
class WarmUp:
    """The fitted warm-up transient and the time it takes to settle within `band_dps`."""

    warm_up_time_s: float  # from power-on
    u_warm_up_time_s: float  # k=1
    band_dps: float
    final_bias_dps: float
    amplitude_dps: float  # A at power-on
    u_amplitude_dps: float
    tau_s: float
    u_tau_s: float
    resolved: bool  # the transient's amplitude is more than twice its uncertainty
    record_end_s: float  # last sample, from power-on
    window_t_s: tuple[float, ...]  # window centres from power-on
    window_bias_dps: tuple[float, ...]

    @property
    def settled_in_record(self) -> bool:
        return self.warm_up_time_s <= self.record_end_s

    def as_dict(self) -> dict[str, object]:
        return {
            "criterion": "fitted exponential b_final + A exp(-t/tau) within +/-band of b_final",
            "warm_up_time_s": self.warm_up_time_s,
            "warm_up_time_uncertainty_k2": 2.0 * self.u_warm_up_time_s,
            "band_dps": self.band_dps,
            "final_bias_dps": self.final_bias_dps,
            "amplitude_dps": self.amplitude_dps,
            "tau_s": self.tau_s,
            "resolved": self.resolved,
            "settled_in_record": self.settled_in_record,
            "record_end_s": self.record_end_s,
            "window_t_s": list(self.window_t_s),
            "window_bias_dps": list(self.window_bias_dps),
        }


def _model(t: NDArray[np.float64], b: float, a: float, tau: float) -> NDArray[np.float64]:
    return np.asarray(b + a * np.exp(-t / tau))


def window_means(
    t_s: NDArray[np.float64], y: NDArray[np.float64], windows: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(centre times, means, standard errors) of `windows` equal-length windows."""
    edges = np.linspace(t_s[0], t_s[-1], windows + 1)
    idx = np.clip(np.searchsorted(edges, t_s, side="right") - 1, 0, windows - 1)
    count = np.bincount(idx, minlength=windows).astype(float)
    keep = count >= 2
    total = np.bincount(idx, weights=y, minlength=windows)
    mean = total / np.maximum(count, 1)
    sq = np.bincount(idx, weights=(y - mean[idx]) ** 2, minlength=windows)
    sem = np.sqrt(sq / np.maximum(count - 1, 1) / np.maximum(count, 1))
    centre = np.bincount(idx, weights=t_s, minlength=windows) / np.maximum(count, 1)
    return centre[keep], mean[keep], sem[keep]


def warm_up_time(
    t_from_power_on_s: ArrayLike,
    rate_dps: ArrayLike,
    band_dps: float,
    windows: int = DEFAULT_WINDOWS,
) -> WarmUp:
    """Fit the bias transient after power-on and the time it takes to enter +/-band_dps."""
    t = finite_1d(t_from_power_on_s, "t_from_power_on_s")
    y = finite_1d(rate_dps, "rate_dps")
    if t.size != y.size:
        raise AnalysisError("give one time per rate sample (two arrays of the same length)")
    if not (math.isfinite(band_dps) and band_dps > 0):
        raise AnalysisError(f"the settling band must be a positive number of deg/s, got {band_dps}")
    if t.size < MIN_WINDOWS * 4 or np.any(np.diff(t) <= 0) or t[0] < 0:
        raise AnalysisError(
            "the warm-up record needs at least 32 samples in rising time from power-on"
        )
    tc, mean, sem = window_means(t, y, windows)
    if tc.size < MIN_WINDOWS:
        raise AnalysisError(f"only {tc.size} windows hold samples; record longer or faster")
    sem = np.maximum(sem, 1e-12)
    span = float(t[-1])
    tail = mean[-max(2, tc.size // 5) :]
    start = (float(np.mean(tail)), float(mean[0] - np.mean(tail)), max(span / 5.0, 1e-3))
    try:
        p, cov = curve_fit(
            _model,
            tc,
            mean,
            p0=start,
            sigma=sem,
            absolute_sigma=False,
            bounds=([-np.inf, -np.inf, 1e-3 * span], [np.inf, np.inf, 10.0 * span]),
            maxfev=5000,
        )
    except (RuntimeError, ValueError) as exc:
        raise AnalysisError(f"the warm-up transient could not be fitted ({exc})") from None
    b_final, amp, tau = (float(x) for x in p)
    cov = np.asarray(cov, dtype=np.float64)
    u_amp = math.sqrt(max(float(cov[1, 1]), 0.0)) if np.isfinite(cov[1, 1]) else math.inf
    u_tau = math.sqrt(max(float(cov[2, 2]), 0.0)) if np.isfinite(cov[2, 2]) else math.inf
    resolved = abs(amp) > 2.0 * u_amp
    if not resolved or abs(amp) <= band_dps:
        t_w, u_t = 0.0, 0.0
    else:
        log_ratio = math.log(abs(amp) / band_dps)
        t_w = tau * log_ratio
        grad = np.array([0.0, tau / amp, log_ratio])  # d t_w / d (b, A, tau)
        u_t = math.sqrt(max(float(grad @ cov @ grad), 0.0))
    return WarmUp(
        warm_up_time_s=t_w,
        u_warm_up_time_s=u_t,
        band_dps=band_dps,
        final_bias_dps=b_final,
        amplitude_dps=amp,
        u_amplitude_dps=u_amp,
        tau_s=tau,
        u_tau_s=u_tau,
        resolved=resolved,
        record_end_s=span,
        window_t_s=tuple(float(x) for x in tc),
        window_bias_dps=tuple(float(x) for x in mean),
    )
