"""Do two estimates of one quantity agree? The normalised difference E_n.

E_n = (a - b) / sqrt(u_a^2 + u_b^2 - 2 cov(a, b)), standard uncertainties; the two agree at
coverage factor k when |E_n| <= k. Used for the stop-method versus rate-table scale at one
condition.

For a good part (honest uncertainties) E_n is about N(0, 1) at each condition, so a fixed
|E_n| <= 3 rejects 0.27 % of good parts per condition, and a part judged at n conditions
fails at least one about n times as often (1.1 % at the 2 x 2's four). The product therefore
states the share of good parts it accepts to reject over all the conditions
(`consistency.false_reject_rate`), and `per_condition_limit` turns it into the |E_n| limit
at each condition (Sidak: 1 - (1 - rate)^(1/n) per condition, split over both tails).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

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


def per_condition_rate(part_rate: float, judgements: int) -> float:
    """The false-reject rate allowed at each of `judgements` independent judgements so that
    a good part fails at least one with probability `part_rate` (Sidak)."""
    if not 0.0 < part_rate < 1.0:
        raise ValueError(f"a false-reject rate is a share in (0, 1), not {part_rate!r}")
    if judgements < 1:
        raise ValueError(f"at least one judgement, not {judgements!r}")
    # 1 - (1 - p)^(1/n), accurate for small p
    return -math.expm1(math.log1p(-part_rate) / judgements)


def per_condition_limit(part_rate: float, judgements: int) -> float:
    """The |E_n| limit at each condition for a per-part false-reject rate over `judgements`
    conditions: E_n ~ N(0, 1) for a good part, both tails (0.1 % over 4: 3.66)."""
    alpha = per_condition_rate(part_rate, judgements)
    return NormalDist().inv_cdf(1.0 - alpha / 2.0)


def part_false_reject_rate(limit: float, judgements: int) -> float:
    """The share of good parts a per-condition |E_n| <= `limit` rejects over `judgements`
    conditions (the inverse of `per_condition_limit`; 3 over 4: 1.07 %)."""
    alpha = 2.0 * (1.0 - NormalDist().cdf(limit))
    return -math.expm1(judgements * math.log1p(-alpha))
