"""Process capability and control-chart rules (pure functions, no I/O).

Cpk's confidence interval is Bissell's normal approximation (Bissell 1990, "How reliable is
your capability index?", Applied Statistics 39):

    Cpk_hat +/- z * sqrt( 1 / (9 n) + Cpk_hat^2 / (2 (n - 1)) )

with z the standard normal quantile of the two-sided confidence level.

The Western Electric rules (Statistical Quality Control Handbook, 1956), on one side of the
centre line, with sigma the chart's standard deviation:
  1. one point beyond 3 sigma;
  2. two of three consecutive points beyond 2 sigma;
  3. four of five consecutive points beyond 1 sigma;
  4. eight consecutive points on the same side of the centre line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

from reports.lot_stats import MIN_CPK_N  # one minimum for the dashboard and the lot report


@dataclass(frozen=True)
class Capability:
    n: int
    mean: float
    sd: float
    low: float | None
    high: float | None
    cpk: float | None  # None when there is no limit, too few values, or no spread
    ci_low: float | None
    ci_high: float | None
    confidence: float
    too_few: bool = False  # fewer than min_n values: no Cpk is given
    min_n: int = MIN_CPK_N
    reason: str | None = None  # why cpk is None, in words for the page


def cpk(mean: float, sd: float, low: float | None, high: float | None) -> float | None:
    """min((high - mean), (mean - low)) / (3 sd) over the limits there are."""
    no_spread = sd <= 1e-12 * max(1.0, abs(mean))  # rounding noise of equal values
    if no_spread or not math.isfinite(sd) or (low is None and high is None):
        return None
    sides = []
    if high is not None:
        sides.append((high - mean) / (3 * sd))
    if low is not None:
        sides.append((mean - low) / (3 * sd))
    return min(sides)


def bissell_interval(cpk_hat: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Bissell's approximate two-sided confidence interval of Cpk from n values."""
    if n < 2:
        raise ValueError(f"a confidence interval of Cpk needs at least 2 values, got {n}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence {confidence} must be between 0 and 1")
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    half = z * math.sqrt(1 / (9 * n) + cpk_hat**2 / (2 * (n - 1)))
    return cpk_hat - half, cpk_hat + half


def capability(n: int, mean: float, sd: float, low: float | None, high: float | None,
               confidence: float = 0.95, min_n: int = MIN_CPK_N) -> Capability:
    """Cpk and its Bissell interval from the sample size, mean and sample standard deviation;
    none below `min_n` values (too_few), with the reason when there is none."""
    need = max(min_n, 2)
    too_few = n < need
    value = None if too_few else cpk(mean, sd, low, high)
    ci = bissell_interval(value, n, confidence) if value is not None else (None, None)
    reason = None if value is not None else no_cpk_reason(n, need, low, high)
    return Capability(n, mean, sd, low, high, value, ci[0], ci[1], confidence, too_few, need,
                      reason)


def no_cpk_reason(n: int, need: int, low: float | None, high: float | None) -> str:
    """Why a measurement has no Cpk: too few values, no limits, or no spread."""
    if n < need:
        return f"too few (n = {n}, need {need})"
    if low is None and high is None:
        return "no limits"
    return "no spread (all values equal)"


def western_electric(values: Sequence[float], centre: float, sigma: float) -> list[list[int]]:
    """For each point, the rules (1-4) it completes; empty lists when sigma is not positive."""
    flags: list[list[int]] = [[] for _ in values]
    if sigma <= 0 or not math.isfinite(sigma):
        return flags
    z = [(v - centre) / sigma for v in values]
    for i in range(len(z)):
        for rule, window, need, beyond in ((1, 1, 1, 3.0), (2, 3, 2, 2.0), (3, 5, 4, 1.0),
                                           (4, 8, 8, 0.0)):
            if i + 1 < window:
                continue
            recent = z[i + 1 - window : i + 1]
            for side in (1.0, -1.0):
                if side * z[i] <= beyond:  # the point completing the run is itself beyond
                    continue
                if sum(1 for x in recent if side * x > beyond) >= need:
                    flags[i].append(rule)
                    break
    return flags


def mean_sd(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (sd 0 for fewer than 2 values)."""
    n = len(values)
    if n == 0:
        return math.nan, 0.0
    m = sum(values) / n
    if n < 2:
        return m, 0.0
    return m, math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1))
