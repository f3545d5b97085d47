"""Temperature fit of order 1, 2 or 3 of bias and scale, with the first-order supply terms.

    bias(T, V)  = b0 + b1 dT + b2 dT^2 + b3 dT^3 + bV dV
    scale(T, V) = s0 (1 + s1 dT + s2 dT^2 + s3 dT^3 + sV dV)        dT = T - T0, dV = V - V0

Order 1 is `temp_supply_fit.fit_temp_supply` itself (today's fit, its interaction check
included), so the coefficients and uncertainties of a first-order run do not change. Orders 2
and 3 are the same weighted least squares (each condition's own uncertainty, not rescaled by
the scatter) on the wider design; the scale is fitted in its linear form
q0 + q1 dT + ... + qV dV and carried to s_k = q_k / q0 through the Jacobian. Order N needs
N + 1 temperatures at least 3 C apart and two supply levels, and at least N + 2 conditions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_supply_fit import (
    COEFFICIENT_NAMES,
    REFERENCE_SUPPLY_V,
    REFERENCE_TEMPERATURE_C,
    ConditionMeasurement,
    TempSupplyFit,
    condition_table,
    fit_temp_supply,
    weighted_lsq,
)

FIT_ORDERS = (1, 2, 3)
# record/calibration names of the terms beyond first order, by order
HIGHER_BIAS_NAMES = {2: "bias_temp_coeff2_dps_per_c2", 3: "bias_temp_coeff3_dps_per_c3"}
HIGHER_SCALE_NAMES = {2: "scale_temp_coeff2_per_c2", 3: "scale_temp_coeff3_per_c3"}
UNITS = {
    "bias_dps": "deg/s",
    "bias_temp_coeff_dps_per_c": "deg/s/C",
    "bias_supply_coeff_dps_per_v": "deg/s/V",
    "scale": "1",
    "scale_temp_coeff_per_c": "1/C",
    "scale_supply_coeff_per_v": "1/V",
    "bias_temp_coeff2_dps_per_c2": "deg/s/C^2",
    "bias_temp_coeff3_dps_per_c3": "deg/s/C^3",
    "scale_temp_coeff2_per_c2": "1/C^2",
    "scale_temp_coeff3_per_c3": "1/C^3",
}
# die temperatures closer than this count as one temperature (the two supply levels of one
# chamber setpoint differ by the self-heating, a degree or so)
_DISTINCT_TEMP_C = 3.0


@dataclass(frozen=True)
class TemperatureFit:
    """Bias and scale against temperature (order 1..3) and supply (first order), k=1 covs.

    `bias_params` is (b0, b1 .. bN, bV); `scale_params` (s0, s1 .. sN, sV), each with its
    covariance in the same order."""

    order: int
    bias_params: NDArray[np.float64]
    bias_covariance: NDArray[np.float64]
    scale_params: NDArray[np.float64]
    scale_covariance: NDArray[np.float64]
    bias_chi2: float
    scale_chi2: float
    dof: int
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C
    reference_supply_v: float = REFERENCE_SUPPLY_V
    first_order: TempSupplyFit | None = None  # order 1: today's fit, unchanged

    def names(self) -> tuple[list[str], list[str]]:
        """(bias names, scale names) in parameter order."""
        bias = ["bias_dps", "bias_temp_coeff_dps_per_c"]
        scale = ["scale", "scale_temp_coeff_per_c"]
        bias += [HIGHER_BIAS_NAMES[k] for k in range(2, self.order + 1)]
        scale += [HIGHER_SCALE_NAMES[k] for k in range(2, self.order + 1)]
        return bias + ["bias_supply_coeff_dps_per_v"], scale + ["scale_supply_coeff_per_v"]

    def value(self, name: str) -> float:
        bias, scale = self.names()
        if name in bias:
            return float(self.bias_params[bias.index(name)])
        return float(self.scale_params[scale.index(name)])

    def uncertainty(self, name: str) -> float:
        """Standard (k=1) uncertainty of one coefficient by its record name."""
        bias, scale = self.names()
        if name in bias:
            i = bias.index(name)
            return math.sqrt(float(self.bias_covariance[i, i]))
        i = scale.index(name)
        return math.sqrt(float(self.scale_covariance[i, i]))

    def _row(self, temp_c: ArrayLike) -> NDArray[np.float64]:
        dt = np.atleast_1d(np.asarray(temp_c, dtype=np.float64)) - self.reference_temperature_c
        return np.column_stack([dt**k for k in range(1, self.order + 1)])

    def bias_at(self, temp_c: ArrayLike, supply_v: float) -> NDArray[np.float64]:
        """Fitted bias (deg/s) at temperatures and one supply level."""
        p = self.bias_params
        dv = supply_v - self.reference_supply_v
        return np.asarray(p[0] + self._row(temp_c) @ p[1 : self.order + 1] + p[-1] * dv)

    def scale_at(self, temp_c: ArrayLike, supply_v: float) -> NDArray[np.float64]:
        """Fitted scale at temperatures and one supply level."""
        p = self.scale_params
        dv = supply_v - self.reference_supply_v
        return np.asarray(p[0] * (1.0 + self._row(temp_c) @ p[1 : self.order + 1] + p[-1] * dv))

    def u_bias_at(self, temp_c: ArrayLike, supply_v: float) -> NDArray[np.float64]:
        """Standard uncertainty of the fitted bias curve (propagated covariance)."""
        dv = supply_v - self.reference_supply_v
        rows = self._row(temp_c)
        jac = np.column_stack([np.ones(len(rows)), rows, np.full(len(rows), dv)])
        return np.sqrt(np.einsum("ij,jk,ik->i", jac, self.bias_covariance, jac))

    def as_calibration_dict(self) -> dict[str, object]:
        """The record's `calibration` block: order 1 exactly today's; orders 2 and 3 add
        their terms and `fit_order`."""
        if self.first_order is not None:
            return self.first_order.as_calibration_dict()
        bias, scale = self.names()
        out: dict[str, object] = {
            name: {"value": self.value(name), "uncertainty_k2": 2.0 * self.uncertainty(name)}
            for name in (*COEFFICIENT_NAMES, *bias[2:-1], *scale[2:-1])
        }
        out["reference_temperature_c"] = self.reference_temperature_c
        out["reference_supply_v"] = self.reference_supply_v
        out["fit_order"] = self.order
        return out


def _chi2(fit: TemperatureFit, conditions: Sequence[ConditionMeasurement]) -> tuple[float, float]:
    chi2_b = chi2_s = 0.0
    for c in conditions:
        chi2_b += float((fit.bias_at(c.temp_c, c.supply_v)[0] - c.bias_dps) / c.u_bias_dps) ** 2
        chi2_s += float((fit.scale_at(c.temp_c, c.supply_v)[0] - c.scale) / c.u_scale) ** 2
    return chi2_b, chi2_s


def _from_first_order(
    fit: TempSupplyFit, conditions: Sequence[ConditionMeasurement]
) -> TemperatureFit:
    c = fit.coefficients
    out = TemperatureFit(
        order=1,
        bias_params=np.array(
            [c.bias_dps, c.bias_temp_coeff_dps_per_c, c.bias_supply_coeff_dps_per_v]
        ),
        bias_covariance=fit.bias_covariance,  # (b0, bT, bV) is already (b0, b1, bV)
        scale_params=np.array([c.scale, c.scale_temp_coeff_per_c, c.scale_supply_coeff_per_v]),
        scale_covariance=fit.scale_covariance,
        bias_chi2=0.0,
        scale_chi2=0.0,
        dof=len(conditions) - 3,
        reference_temperature_c=c.reference_temperature_c,
        reference_supply_v=c.reference_supply_v,
        first_order=fit,
    )
    chi2_b, chi2_s = _chi2(out, conditions)
    return replace(out, bias_chi2=chi2_b, scale_chi2=chi2_s)


def _wls(
    design: NDArray[np.float64], y: NDArray[np.float64], u: NDArray[np.float64], order: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    return weighted_lsq(
        design, y, u, 1e14,
        f"the conditions cannot separate an order-{order} temperature fit from the supply "
        f"terms: measure at {order + 1} or more temperatures and two supply levels",
    )


def distinct_temperatures(temps_c: Sequence[float]) -> int:
    """How many temperatures at least 3 C apart the conditions hold."""
    count, last = 0, -math.inf
    for t in sorted(temps_c):
        if t - last >= _DISTINCT_TEMP_C:
            count, last = count + 1, t
    return count


def fit_temperature(
    conditions: Sequence[ConditionMeasurement],
    order: int,
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C,
    reference_supply_v: float = REFERENCE_SUPPLY_V,
) -> TemperatureFit:
    """Fit bias and scale against temperature to `order` (1, 2 or 3) and supply (first)."""
    if order not in FIT_ORDERS:
        raise AnalysisError(f"fit order {order} is not supported; use 1, 2 or 3")
    if order == 1:
        fit = fit_temp_supply(conditions, reference_temperature_c, reference_supply_v)
        return _from_first_order(fit, conditions)
    n_temps = distinct_temperatures([c.temp_c for c in conditions])
    if n_temps < order + 1 or len(conditions) < order + 2:
        raise AnalysisError(
            f"an order-{order} temperature fit needs {order + 1} temperatures (at least 3 C "
            f"apart) and {order + 2} conditions; got {n_temps} temperature(s) in "
            f"{len(conditions)} condition(s): add temperatures to the procedure or lower fit.order"
        )
    arr = condition_table(conditions)
    dt = arr[:, 0] - reference_temperature_c
    dv = arr[:, 1] - reference_supply_v
    design = np.column_stack([np.ones_like(dt), *(dt**k for k in range(1, order + 1)), dv])
    pb, cov_b, chi2_b = _wls(design, arr[:, 2], arr[:, 3], order)
    q, cov_q, chi2_s = _wls(design, arr[:, 4], arr[:, 5], order)
    q0 = float(q[0])
    jac = np.zeros((q.size, q.size))
    jac[0, 0] = 1.0
    for i in range(1, q.size):
        jac[i, 0] = -q[i] / q0**2
        jac[i, i] = 1.0 / q0
    s = np.concatenate([[q0], q[1:] / q0])
    return TemperatureFit(
        order=order,
        bias_params=pb,
        bias_covariance=cov_b,
        scale_params=s,
        scale_covariance=jac @ cov_q @ jac.T,
        bias_chi2=chi2_b,
        scale_chi2=chi2_s,
        dof=len(conditions) - design.shape[1],
        reference_temperature_c=reference_temperature_c,
        reference_supply_v=reference_supply_v,
    )


def record_summary(
    bias_fit: TemperatureFit, scale_fit: TemperatureFit, points: list[dict[str, Any]]
) -> dict[str, Any]:
    """record.analysis["temperature_fit"]: the bias terms from `bias_fit`, the scale terms
    from `scale_fit` (each paired with the die temperature of its own windows), the points
    fitted, and what the certificate's section draws (reports/cert_temperature_fit.py)."""
    bias_names, _ = bias_fit.names()
    _, scale_names = scale_fit.names()
    coefficients = [
        {
            "name": name,
            "value": fit.value(name),
            "uncertainty_k2": 2.0 * fit.uncertainty(name),
            "units": UNITS[name],
        }
        for fit, names in ((bias_fit, bias_names), (scale_fit, scale_names))
        for name in names
    ]
    return {
        "order": bias_fit.order,
        "reference_temperature_c": bias_fit.reference_temperature_c,
        "reference_supply_v": bias_fit.reference_supply_v,
        "coefficients": coefficients,
        "bias_params": [float(x) for x in bias_fit.bias_params],
        "scale_params": [float(x) for x in scale_fit.scale_params],
        "bias_chi2": bias_fit.bias_chi2,
        "scale_chi2": scale_fit.scale_chi2,
        "dof": bias_fit.dof,
        "points": points,
    }
