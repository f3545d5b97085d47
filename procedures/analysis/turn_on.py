"""Turn-on to turn-on bias repeatability (IEEE Std 1431, 'turn-on to turn-on bias').

The part is powered off, left off, powered on and its bias measured, N times; the
repeatability is the sample standard deviation (n - 1) of the N biases, as the standard
defines it. Its standard uncertainty is that of a normal sample's standard deviation:
u(s) = s sqrt(1 - c4^2) / c4 with c4 = sqrt(2 / (n - 1)) Gamma(n / 2) / Gamma((n - 1) / 2)
(about s / sqrt(2 (n - 1)) for large n). With few turn-ons the spread of s is skewed, so
s +/- 2 u(s) covers the true sigma less often than 95 % (about 90 % at n = 8); the exact
95 % interval from the chi-square distribution, s sqrt((n - 1) / chi2(0.975 | 0.025, n - 1)),
is given beside it.

Each bias carries its own measurement uncertainty (noise over its window, wander); their
root mean square is the floor under the spread that repeats of a perfectly repeatable part
would still show. It is reported beside the repeatability, with the spread left after taking
it out in quadrature (`excess_dps`), so a figure near the floor reads as 'not resolved'.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.stats import chi2

from procedures.analysis.errors import AnalysisError

MIN_TURN_ONS = 3


def c4(n: int) -> float:
    """Bias factor of the sample standard deviation of n normal values: E[s] = c4 sigma."""
    return math.exp(
        0.5 * math.log(2.0 / (n - 1)) + math.lgamma(n / 2.0) - math.lgamma((n - 1) / 2.0)
    )


@lru_cache(maxsize=256)
def _chi2_factors(n: int) -> tuple[float, float]:
    """(low, high) factors on s of the exact 95 % interval for sigma from n values."""
    return (
        math.sqrt((n - 1) / float(chi2.ppf(0.975, n - 1))),
        math.sqrt((n - 1) / float(chi2.ppf(0.025, n - 1))),
    )


@dataclass(frozen=True)
class TurnOnRepeatability:
    """Spread of the biases measured after each power-on; all figures k=1, deg/s."""

    repeatability_dps: float  # sample standard deviation of the biases
    u_repeatability_dps: float
    mean_bias_dps: float
    noise_floor_dps: float  # rms of the biases' own measurement uncertainties
    excess_dps: float  # sqrt(max(s^2 - floor^2, 0))
    biases_dps: tuple[float, ...]
    u_biases_dps: tuple[float, ...]
    interval_95_dps: tuple[float, float]  # exact chi-square interval for the true sigma

    @property
    def n(self) -> int:
        return len(self.biases_dps)

    @property
    def resolved(self) -> bool:
        """The spread stands out of the measurement noise (more than twice its floor)."""
        return self.repeatability_dps > 2.0 * self.noise_floor_dps

    def as_dict(self) -> dict[str, object]:
        return {
            "repeatability_dps": self.repeatability_dps,
            "repeatability_uncertainty_k2": 2.0 * self.u_repeatability_dps,
            "mean_bias_dps": self.mean_bias_dps,
            "noise_floor_dps": self.noise_floor_dps,
            "excess_dps": self.excess_dps,
            "interval_95_dps": list(self.interval_95_dps),
            "resolved": self.resolved,
            "biases_dps": list(self.biases_dps),
            "bias_uncertainties_dps": list(self.u_biases_dps),
        }


def turn_on_repeatability(
    biases_dps: Sequence[float], u_biases_dps: Sequence[float]
) -> TurnOnRepeatability:
    """Repeatability of the biases after N >= 3 power-ons (each with its k=1 uncertainty)."""
    b = np.asarray(biases_dps, dtype=np.float64)
    u = np.asarray(u_biases_dps, dtype=np.float64)
    if b.ndim != 1 or b.shape != u.shape:
        raise AnalysisError("give one uncertainty per bias (two sequences of the same length)")
    if b.size < MIN_TURN_ONS:
        raise AnalysisError(
            f"{b.size} turn-on(s) measured; the repeatability needs at least {MIN_TURN_ONS} "
            "(set turn_on_repeatability.turn_ons higher)"
        )
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(u))) or np.any(u < 0):
        raise AnalysisError("a bias or its uncertainty is not a finite number >= 0: repeat it")
    n = int(b.size)
    s = float(np.std(b, ddof=1))
    k = c4(n)
    floor = float(np.sqrt(np.mean(u**2)))
    return TurnOnRepeatability(
        repeatability_dps=s,
        u_repeatability_dps=s * math.sqrt(1.0 - k * k) / k,
        mean_bias_dps=float(np.mean(b)),
        noise_floor_dps=floor,
        excess_dps=math.sqrt(max(s * s - floor * floor, 0.0)),
        biases_dps=tuple(float(x) for x in b),
        u_biases_dps=tuple(float(x) for x in u),
        interval_95_dps=(s * _chi2_factors(n)[0], s * _chi2_factors(n)[1]),
    )
