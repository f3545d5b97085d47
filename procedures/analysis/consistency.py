"""Do two estimates of one quantity agree? The normalised difference E_n.

E_n = (a - b) / sqrt(u_a^2 + u_b^2 - 2 cov(a, b)), standard uncertainties; the two agree at
coverage factor k when |E_n| <= k. Used for the stop-method versus rate-table scale at one
condition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from procedures.analysis.errors import AnalysisError
from procedures.analysis.rate_table import RateTableFit
from procedures.analysis.stop_method import StopMethodResult


@dataclass(frozen=True)
class Consistency:
    value_a: float
    value_b: float
    difference: float  # a - b
    u_difference: float  # k=1
    normalised_difference: float  # E_n
    k: float

    @property
    def consistent(self) -> bool:
        return abs(self.normalised_difference) <= self.k


def normalised_difference(
    value_a: float,
    u_a: float,
    value_b: float,
    u_b: float,
    covariance: float = 0.0,
    k: float = 2.0,
) -> Consistency:
    var = u_a**2 + u_b**2 - 2.0 * covariance
    if not (math.isfinite(var) and var > 0.0):
        raise AnalysisError(
            "the combined uncertainty of the two estimates is not positive: give each its "
            "standard uncertainty"
        )
    u = math.sqrt(var)
    d = value_a - value_b
    return Consistency(
        value_a=value_a, value_b=value_b, difference=d, u_difference=u,
        normalised_difference=d / u, k=k,
    )


def stop_vs_rate_table(
    stop: StopMethodResult, table: RateTableFit, k: float = 2.0
) -> Consistency:
    """Stop-method scale (a) against rate-table scale (b) at the same condition."""
    if stop.scale is None or stop.u_scale is None:
        raise AnalysisError(
            "the stop method gave no scale (" + ("; ".join(stop.warnings) or "no move") + ")"
        )
    return normalised_difference(stop.scale, stop.u_scale, table.scale, table.u_scale, k=k)
