"""First-order temperature and supply model of bias and scale, fitted over the conditions.

    bias(T, V)  = b0 + bT (T - T0) + bV (V - V0)
    scale(T, V) = s0 (1 + sT (T - T0) + sV (V - V0))

Weighted least squares with each condition's own uncertainty (known, not rescaled by the
scatter), so the covariance of the coefficients is the propagated measurement uncertainty. A
bias may carry a component common to every condition of the part (`u_bias_common_dps`: the
hysteresis correction's, procedures.analysis.hysteresis, the same unknown at each condition):
the bias fit then weighs with the full covariance diag(u^2) + c c^T (generalised least
squares), so that component reaches the coefficients as the correlated error it is.
The scale model is fitted in its linear form s0 + a dT + c dV and carried to sT = a / s0,
sV = c / s0 through the Jacobian. A 2 x 2 design has one spare degree of freedom: it is
reported as the interaction term (the T x V coefficient of the saturated model) with its
uncertainty and its normalised value, which should lie within +/-2 when first order holds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis.errors import AnalysisError

REFERENCE_TEMPERATURE_C = 25.0
REFERENCE_SUPPLY_V = 5.0


@dataclass(frozen=True)
class ConditionMeasurement:
    """Bias and scale measured at one (temperature, supply) condition; u_* are k=1."""

    temp_c: float  # the part's die temperature during the measurement
    supply_v: float  # measured at the part
    bias_dps: float
    u_bias_dps: float
    scale: float
    u_scale: float
    # k=1, fully correlated between the conditions (signed: it may act with opposite sign
    # at a condition reached from the other side); 0 for none
    u_bias_common_dps: float = 0.0


@dataclass(frozen=True)
class FirstOrderCoefficients:
    """The six coefficients the part is programmed with, about (T0, V0)."""

    bias_dps: float
    bias_temp_coeff_dps_per_c: float
    bias_supply_coeff_dps_per_v: float
    scale: float
    scale_temp_coeff_per_c: float
    scale_supply_coeff_per_v: float
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C
    reference_supply_v: float = REFERENCE_SUPPLY_V

    def bias_at(self, temp_c: ArrayLike, supply_v: ArrayLike) -> NDArray[np.float64]:
        dt = np.asarray(temp_c, dtype=np.float64) - self.reference_temperature_c
        dv = np.asarray(supply_v, dtype=np.float64) - self.reference_supply_v
        return np.asarray(
            self.bias_dps
            + self.bias_temp_coeff_dps_per_c * dt
            + self.bias_supply_coeff_dps_per_v * dv
        )

    def scale_at(self, temp_c: ArrayLike, supply_v: ArrayLike) -> NDArray[np.float64]:
        dt = np.asarray(temp_c, dtype=np.float64) - self.reference_temperature_c
        dv = np.asarray(supply_v, dtype=np.float64) - self.reference_supply_v
        return np.asarray(
            self.scale
            * (1.0 + self.scale_temp_coeff_per_c * dt + self.scale_supply_coeff_per_v * dv)
        )


COEFFICIENT_NAMES = (
    "bias_dps",
    "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale",
    "scale_temp_coeff_per_c",
    "scale_supply_coeff_per_v",
)


@dataclass(frozen=True)
class InteractionCheck:
    """The spare degree of freedom: T x V interaction of the saturated model (k=1)."""

    bias_interaction_dps_per_c_v: float
    u_bias_interaction_dps_per_c_v: float
    scale_interaction_per_c_v: float
    u_scale_interaction_per_c_v: float
    bias_chi2: float  # of the first-order fit, on `dof` degrees of freedom
    scale_chi2: float
    dof: int

    @property
    def bias_normalised(self) -> float:
        return self.bias_interaction_dps_per_c_v / self.u_bias_interaction_dps_per_c_v

    @property
    def scale_normalised(self) -> float:
        return self.scale_interaction_per_c_v / self.u_scale_interaction_per_c_v

    def consistent(self, k: float = 2.0) -> bool:
        return abs(self.bias_normalised) <= k and abs(self.scale_normalised) <= k

    def as_dict(self) -> dict[str, float]:
        return {
            "bias_interaction_dps_per_c_v": self.bias_interaction_dps_per_c_v,
            "bias_interaction_uncertainty_k2": 2.0 * self.u_bias_interaction_dps_per_c_v,
            "bias_interaction_normalised": self.bias_normalised,
            "scale_interaction_per_c_v": self.scale_interaction_per_c_v,
            "scale_interaction_uncertainty_k2": 2.0 * self.u_scale_interaction_per_c_v,
            "scale_interaction_normalised": self.scale_normalised,
            "bias_chi2": self.bias_chi2,
            "scale_chi2": self.scale_chi2,
            "dof": float(self.dof),
        }


@dataclass(frozen=True)
class TempSupplyFit:
    coefficients: FirstOrderCoefficients
    bias_covariance: NDArray[np.float64]  # over (b0, bT, bV)
    scale_covariance: NDArray[np.float64]  # over (s0, sT, sV)
    interaction: InteractionCheck | None  # None when the design has no spare point

    def uncertainty(self, name: str) -> float:
        """Standard (k=1) uncertainty of one coefficient, by its COEFFICIENT_NAMES name."""
        i = COEFFICIENT_NAMES.index(name)
        cov = self.bias_covariance if i < 3 else self.scale_covariance
        return math.sqrt(float(cov[i % 3, i % 3]))

    def uncertainty_k2(self, name: str) -> float:
        return 2.0 * self.uncertainty(name)

    def as_calibration_dict(self) -> dict[str, object]:
        """The pinned `calibration` block of record.json (values with k=2 uncertainties)."""
        out: dict[str, object] = {
            name: {
                "value": float(getattr(self.coefficients, name)),
                "uncertainty_k2": self.uncertainty_k2(name),
            }
            for name in COEFFICIENT_NAMES
        }
        out["reference_temperature_c"] = self.coefficients.reference_temperature_c
        out["reference_supply_v"] = self.coefficients.reference_supply_v
        if self.interaction is not None:
            out["interaction_check"] = self.interaction.as_dict()
        return out


def weighted_lsq(
    design: NDArray[np.float64],
    y: NDArray[np.float64],
    u: NDArray[np.float64],
    max_condition: float,
    refusal: str,
    common: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Weighted least squares of `y` (standard uncertainties `u`) on the design's columns:
    the parameters, their covariance and chi-square; AnalysisError(`refusal`) when the
    normal matrix's condition number exceeds `max_condition` (the conditions cannot tell
    the columns apart). `common`: a k=1 error shared by every row (signed per row), making
    the rows' covariance diag(u^2) + common common^T (generalised least squares)."""
    rows_cov = np.diag(u**2)
    if common is not None:
        rows_cov = rows_cov + np.outer(common, common)
    w_mat = np.linalg.inv(rows_cov)
    a = design.T @ w_mat @ design
    if np.linalg.cond(a) > max_condition:
        raise AnalysisError(refusal)
    cov = np.asarray(np.linalg.inv(a), dtype=np.float64)
    p = cov @ (design.T @ (w_mat @ y))
    r = y - design @ p
    return p, cov, float(r @ w_mat @ r)


def _wls(
    design: NDArray[np.float64], y: NDArray[np.float64], u: NDArray[np.float64],
    common: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    return weighted_lsq(
        design, y, u, 1e12,
        "the conditions do not separate temperature from supply: measure at two "
        "temperatures and two supply levels (a 2 x 2 design)", common,
    )


def condition_table(conditions: Sequence[ConditionMeasurement]) -> NDArray[np.float64]:
    """The conditions as rows of temp_c, supply_v, bias_dps, u_bias_dps, scale, u_scale;
    AnalysisError when a value is not finite or an uncertainty not positive."""
    arr = np.array(
        [[c.temp_c, c.supply_v, c.bias_dps, c.u_bias_dps, c.scale, c.u_scale] for c in conditions],
        dtype=np.float64,
    )
    if not np.all(np.isfinite(arr)):
        raise AnalysisError("a condition holds NaN or infinite values: repeat that condition")
    if np.any(arr[:, 3] <= 0) or np.any(arr[:, 5] <= 0):
        raise AnalysisError("each condition needs positive u_bias_dps and u_scale")
    return arr


def fit_temp_supply(
    conditions: Sequence[ConditionMeasurement],
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C,
    reference_supply_v: float = REFERENCE_SUPPLY_V,
) -> TempSupplyFit:
    """Fit the first-order model to three or more conditions (normally the 2 x 2 design)."""
    if len(conditions) < 3:
        raise AnalysisError(
            f"{len(conditions)} condition(s) given; the first-order fit needs at least three "
            "(normally two temperatures x two supply levels)"
        )
    arr = condition_table(conditions)
    dt = arr[:, 0] - reference_temperature_c
    dv = arr[:, 1] - reference_supply_v
    design = np.column_stack([np.ones_like(dt), dt, dv])

    common = np.array([c.u_bias_common_dps for c in conditions], dtype=np.float64)
    pb, cov_b, chi2_b = _wls(design, arr[:, 2], arr[:, 3], common)
    q, cov_q, chi2_s = _wls(design, arr[:, 4], arr[:, 5])
    s0 = float(q[0])
    jac = np.array(
        [[1.0, 0.0, 0.0], [-q[1] / s0**2, 1.0 / s0, 0.0], [-q[2] / s0**2, 0.0, 1.0 / s0]]
    )
    cov_s = jac @ cov_q @ jac.T
    coeffs = FirstOrderCoefficients(
        bias_dps=float(pb[0]),
        bias_temp_coeff_dps_per_c=float(pb[1]),
        bias_supply_coeff_dps_per_v=float(pb[2]),
        scale=s0,
        scale_temp_coeff_per_c=float(q[1] / s0),
        scale_supply_coeff_per_v=float(q[2] / s0),
        reference_temperature_c=reference_temperature_c,
        reference_supply_v=reference_supply_v,
    )
    interaction = None
    dof = len(conditions) - 3
    if dof >= 1:
        full = np.column_stack([design, dt * dv])
        try:
            pbi, cov_bi, _ = _wls(full, arr[:, 2], arr[:, 3], common)
            psi, cov_si, _ = _wls(full, arr[:, 4], arr[:, 5])
        except AnalysisError:
            pass  # the design cannot separate an interaction (e.g. three levels on a line)
        else:
            interaction = InteractionCheck(
                bias_interaction_dps_per_c_v=float(pbi[3]),
                u_bias_interaction_dps_per_c_v=math.sqrt(cov_bi[3, 3]),
                scale_interaction_per_c_v=float(psi[3] / psi[0]),
                u_scale_interaction_per_c_v=math.sqrt(cov_si[3, 3]) / abs(float(psi[0])),
                bias_chi2=chi2_b,
                scale_chi2=chi2_s,
                dof=dof,
            )
    return TempSupplyFit(
        coefficients=coeffs, bias_covariance=cov_b, scale_covariance=cov_s, interaction=interaction
    )
