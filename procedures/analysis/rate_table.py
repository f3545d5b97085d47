"""Rate-table scale-factor fit (IEEE Std 1431): output against encoder-derived input rate.

Each plateau contributes its mean output (with the Allan-based uncertainty of
`bias.window_mean`) and its reference rate from the encoder angle over the plateau (with the
uncertainty of counts and time stamps, `reference_rate_from_encoder`), never the commanded
rate. The line y = K w + b is fitted by weighted least squares with the reference-rate
uncertainty carried into the output as K * u(w) (effective variance). Reported:

- scale K and bias b with their covariance;
- nonlinearity: the largest residual from that line over full-scale output K * FS, in % FS;
- asymmetry: (K+ - K-) / mean(K) in ppm, from separate slopes for positive and negative
  rates sharing one zero-rate bias (the output at rest is one number);
- the quadratic coefficient of a second-order fit, for diagnosis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis._checks import finite_1d, positive
from procedures.analysis.errors import AnalysisError

U32_MODULO = 1 << 32


@dataclass(frozen=True)
class ReferenceRate:
    """Mean table rate over a plateau from the encoder, with its standard uncertainty."""

    rate_dps: float
    u_rate_dps: float  # k=1
    angle_deg: float
    duration_s: float


def reference_rate_from_encoder(
    counts: ArrayLike,
    controller_time_s: ArrayLike,
    counts_per_rev: float,
    time_resolution_s: float = 1e-3,
    counts_modulo: int = U32_MODULO,
) -> ReferenceRate:
    """Plateau rate = encoder angle between the first and last reading / their time apart.

    `counts` are raw readings that may wrap at `counts_modulo`; consecutive readings must be
    less than half a wrap apart. Each end contributes a quantisation of one count and a time
    stamp rounded to `time_resolution_s` (both uniform, hence the 1/sqrt(12)).
    """
    c = np.asarray(counts, dtype=np.int64)
    t = finite_1d(controller_time_s, "controller_time_s", 2)
    if c.ndim != 1 or c.size != t.size:
        raise AnalysisError(
            f"counts ({c.size}) and controller_time_s ({t.size}) must be 1-D and of one length"
        )
    cpr = positive(counts_per_rev, "counts_per_rev")
    half = counts_modulo // 2
    steps = (np.diff(c) + half) % counts_modulo - half  # signed, unwrapped
    delta_counts = float(steps.sum())
    duration = float(t[-1] - t[0])
    if duration <= 0.0:
        raise AnalysisError(
            "controller_time_s must increase over the plateau (last reading after the first)"
        )
    deg_per_count = 360.0 / cpr
    angle = delta_counts * deg_per_count
    rate = angle / duration
    u_counts = math.sqrt(2.0 / 12.0)  # two readings, each rounded to one count
    u_time = time_resolution_s * math.sqrt(2.0 / 12.0)
    u_rate = math.hypot(u_counts * deg_per_count / duration, rate * u_time / duration)
    return ReferenceRate(rate_dps=rate, u_rate_dps=u_rate, angle_deg=angle, duration_s=duration)


@dataclass(frozen=True)
class RateTableFit:
    """Result of the IEEE 1431 fit; every u_* is a standard (k=1) uncertainty."""

    scale: float  # output / input
    u_scale: float
    bias_dps: float
    u_bias_dps: float
    cov_scale_bias: float
    nonlinearity_pct_fs: float
    u_nonlinearity_pct_fs: float
    asymmetry_ppm: float
    u_asymmetry_ppm: float
    scale_positive: float
    u_scale_positive: float
    scale_negative: float
    u_scale_negative: float
    k2_per_dps: float  # y = b + K w + k2 w^2, for diagnosis only
    u_k2_per_dps: float
    full_scale_dps: float
    input_rate_dps: tuple[float, ...]
    residual_dps: tuple[float, ...]
    chi2_per_dof: float  # >> 1 means the straight line does not describe the part

    @property
    def scale_correction(self) -> float:
        return 1.0 / self.scale

    @property
    def u_scale_correction(self) -> float:
        return self.u_scale / self.scale**2

    @property
    def u_scale_k2(self) -> float:
        return 2.0 * self.u_scale

    @property
    def u_bias_dps_k2(self) -> float:
        return 2.0 * self.u_bias_dps


def _wls(
    design: NDArray[np.float64], y: NDArray[np.float64], var: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    w = 1.0 / var
    a = design.T @ (design * w[:, None])
    cov = np.asarray(np.linalg.inv(a), dtype=np.float64)
    p = cov @ (design.T @ (w * y))
    return p, cov


def fit_rate_table(
    input_rate_dps: ArrayLike,
    u_input_rate_dps: ArrayLike,
    output_dps: ArrayLike,
    u_output_dps: ArrayLike,
    full_scale_dps: float,
) -> RateTableFit:
    """Fit scale, bias, nonlinearity and asymmetry from one condition's plateaus."""
    w = finite_1d(input_rate_dps, "input_rate_dps", 3)
    y = finite_1d(output_dps, "output_dps", 3)
    uw = finite_1d(u_input_rate_dps, "u_input_rate_dps", 3)
    uy = finite_1d(u_output_dps, "u_output_dps", 3)
    if not (w.size == y.size == uw.size == uy.size):
        raise AnalysisError(
            "input_rate_dps, u_input_rate_dps, output_dps and u_output_dps need one entry "
            f"per plateau, got {w.size}, {uw.size}, {y.size}, {uy.size}"
        )
    fs = positive(full_scale_dps, "full_scale_dps")
    if np.any(uy <= 0.0) or np.any(uw < 0.0):
        raise AnalysisError(
            "u_output_dps must be positive and u_input_rate_dps non-negative: "
            "give each plateau its real uncertainty"
        )
    n_pos, n_neg = int(np.sum(w > 0)), int(np.sum(w < 0))
    if n_pos < 1 or n_neg < 1:
        raise AnalysisError(
            f"the rate set has {n_pos} positive and {n_neg} negative rates: it must span the "
            "range in both directions (IEEE 1431)"
        )
    if np.unique(w).size < 3:
        raise AnalysisError("the rate set needs at least three distinct rates")

    line = np.column_stack([w, np.ones_like(w)])
    scale = float(np.polyfit(w, y, 1)[0])
    for _ in range(3):  # effective variance depends on the slope; converges in two passes
        var = uy**2 + (scale * uw) ** 2
        p, cov = _wls(line, y, var)
        scale = float(p[0])
    bias = float(p[1])
    resid = y - line @ p
    # Residual variance: V - X C X^T (diagonal); gives each residual its own uncertainty.
    var_resid = var - np.einsum("ij,jk,ik->i", line, cov, line)
    i_max = int(np.argmax(np.abs(resid)))
    fs_out = abs(scale) * fs
    nl = 100.0 * abs(float(resid[i_max])) / fs_out
    u_nl = 100.0 * math.sqrt(max(float(var_resid[i_max]), 0.0)) / fs_out
    dof = w.size - 2
    chi2 = float(np.sum(resid**2 / var)) / dof if dof > 0 else float("nan")

    asym = _asymmetry(w, y, var)
    k2, u_k2 = _quadratic(w, y, var)
    return RateTableFit(
        scale=scale,
        u_scale=math.sqrt(cov[0, 0]),
        bias_dps=bias,
        u_bias_dps=math.sqrt(cov[1, 1]),
        cov_scale_bias=float(cov[0, 1]),
        nonlinearity_pct_fs=nl,
        u_nonlinearity_pct_fs=u_nl,
        asymmetry_ppm=asym[0],
        u_asymmetry_ppm=asym[1],
        scale_positive=asym[2],
        u_scale_positive=asym[3],
        scale_negative=asym[4],
        u_scale_negative=asym[5],
        k2_per_dps=k2,
        u_k2_per_dps=u_k2,
        full_scale_dps=fs,
        input_rate_dps=tuple(float(v) for v in w),
        residual_dps=tuple(float(v) for v in resid),
        chi2_per_dof=chi2,
    )


def _asymmetry(
    w: NDArray[np.float64], y: NDArray[np.float64], var: NDArray[np.float64]
) -> tuple[float, float, float, float, float, float]:
    design = np.column_stack([np.maximum(w, 0.0), np.minimum(w, 0.0), np.ones_like(w)])
    p, cov = _wls(design, y, var)
    kp, kn = float(p[0]), float(p[1])
    mean_k = 0.5 * (kp + kn)
    a = (kp - kn) / mean_k
    # d a / d kp = kn / mean^2 ... from a = 2 (kp - kn) / (kp + kn)
    s = kp + kn
    grad = np.array([4.0 * kn / s**2, -4.0 * kp / s**2])
    u_a = math.sqrt(float(grad @ cov[:2, :2] @ grad))
    return (
        a * 1e6,
        u_a * 1e6,
        kp,
        math.sqrt(cov[0, 0]),
        kn,
        math.sqrt(cov[1, 1]),
    )


def _quadratic(
    w: NDArray[np.float64], y: NDArray[np.float64], var: NDArray[np.float64]
) -> tuple[float, float]:
    design = np.column_stack([w, np.ones_like(w), w**2])
    p, cov = _wls(design, y, var)
    return float(p[2]), math.sqrt(cov[2, 2])
