"""Apply the first-order correction to raw output and judge the result at verification rates.

The corrected rate is (raw - bias(T, V)) / scale(T, V) with the part's die temperature and
measured supply. Residual errors are reported as % of full scale and as ppm of reading (the
latter only where the reference rate is large enough for a reading-relative error to mean
something).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis._checks import finite_1d, positive
from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_supply_fit import FirstOrderCoefficients, TempSupplyFit


def correct_rate(
    raw_dps: ArrayLike,
    temp_c: ArrayLike,
    supply_v: ArrayLike,
    coefficients: FirstOrderCoefficients,
) -> NDArray[np.float64]:
    """Corrected rate in deg/s; temp_c and supply_v are scalars or one per sample."""
    raw = np.asarray(raw_dps, dtype=np.float64)
    bias = coefficients.bias_at(temp_c, supply_v)
    scale = coefficients.scale_at(temp_c, supply_v)
    if np.any(scale == 0):
        raise AnalysisError("the coefficients give a zero scale factor: refit them")
    return np.asarray((raw - bias) / scale)


def correction_uncertainty_dps(
    fit: TempSupplyFit, rate_dps: ArrayLike, temp_c: ArrayLike, supply_v: ArrayLike
) -> NDArray[np.float64]:
    """Standard uncertainty the fitted coefficients add to a corrected rate (k=1).

    Propagates both coefficient covariances through w = (y - bias(T, V)) / scale(T, V);
    add it in quadrature to the measurement's own uncertainty.
    """
    c = fit.coefficients
    w = np.asarray(rate_dps, dtype=np.float64)
    dt = np.asarray(temp_c, dtype=np.float64) - c.reference_temperature_c
    dv = np.asarray(supply_v, dtype=np.float64) - c.reference_supply_v
    w, dt, dv = np.broadcast_arrays(w, dt, dv)
    scale = c.scale_at(c.reference_temperature_c + dt, c.reference_supply_v + dv)
    ones = np.ones_like(w)
    g_bias = -np.stack([ones, dt, dv], axis=-1) / scale[..., None]
    # d scale / d (s0, sT, sV), then d w / d scale = -w / scale
    ds = np.stack(
        [scale / c.scale, c.scale * dt, c.scale * dv], axis=-1
    )
    g_scale = -(w / scale)[..., None] * ds
    var = np.einsum("...i,ij,...j->...", g_bias, fit.bias_covariance, g_bias) + np.einsum(
        "...i,ij,...j->...", g_scale, fit.scale_covariance, g_scale
    )
    return np.asarray(np.sqrt(var))


@dataclass(frozen=True)
class VerificationPoint:
    """One verification plateau; u_* are standard (k=1) uncertainties."""

    reference_rate_dps: float
    corrected_rate_dps: float
    error_dps: float
    u_error_dps: float
    error_pct_fs: float
    u_error_pct_fs: float
    error_ppm_of_reading: float | None  # None below min_rate_for_ppm_dps
    u_error_ppm_of_reading: float | None


@dataclass(frozen=True)
class VerificationResult:
    points: tuple[VerificationPoint, ...]
    full_scale_dps: float
    max_abs_error_pct_fs: float
    max_abs_error_ppm_of_reading: float | None

    def within(self, limit_pct_fs: float) -> bool:
        return self.max_abs_error_pct_fs <= limit_pct_fs


def verify_correction(
    reference_rate_dps: ArrayLike,
    u_reference_rate_dps: ArrayLike,
    corrected_rate_dps: ArrayLike,
    u_corrected_rate_dps: ArrayLike,
    full_scale_dps: float,
    min_rate_for_ppm_dps: float = 1.0,
) -> VerificationResult:
    """Residual error of corrected plateau means against their encoder reference rates."""
    ref = finite_1d(reference_rate_dps, "reference_rate_dps")
    u_ref = finite_1d(u_reference_rate_dps, "u_reference_rate_dps")
    out = finite_1d(corrected_rate_dps, "corrected_rate_dps")
    u_out = finite_1d(u_corrected_rate_dps, "u_corrected_rate_dps")
    if not (ref.size == u_ref.size == out.size == u_out.size):
        raise AnalysisError("give one reference rate, corrected rate and uncertainty per plateau")
    fs = positive(full_scale_dps, "full_scale_dps")
    points = []
    for r, ur, o, uo in zip(ref, u_ref, out, u_out, strict=True):
        err = float(o - r)
        u_err = math.hypot(float(ur), float(uo))
        ppm = u_ppm = None
        if abs(r) >= min_rate_for_ppm_dps:
            ppm = err / abs(float(r)) * 1e6
            u_ppm = u_err / abs(float(r)) * 1e6
        points.append(
            VerificationPoint(
                reference_rate_dps=float(r),
                corrected_rate_dps=float(o),
                error_dps=err,
                u_error_dps=u_err,
                error_pct_fs=100.0 * err / fs,
                u_error_pct_fs=100.0 * u_err / fs,
                error_ppm_of_reading=ppm,
                u_error_ppm_of_reading=u_ppm,
            )
        )
    ppms = [abs(p.error_ppm_of_reading) for p in points if p.error_ppm_of_reading is not None]
    return VerificationResult(
        points=tuple(points),
        full_scale_dps=fs,
        max_abs_error_pct_fs=max(abs(p.error_pct_fs) for p in points),
        max_abs_error_ppm_of_reading=max(ppms) if ppms else None,
    )
