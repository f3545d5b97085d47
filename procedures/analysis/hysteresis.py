"""The bias hysteresis between heating and cooling: from which side each condition was reached.

A MEMS gyro's bias at one temperature differs by h between reaching it by heating (+h/2 about
the midline) and by cooling (-h/2), switched by a reversal of the temperature of about twice
the width w (docs/simulated-bench.md). The station follows each part's own die temperature
sensor from power-on with a play (backlash) operator of the product's declared width:

    c <- clamp(c, T - w, T + w),   state = (T - c) / w   in [-1, 1]

(+1: reached by heating, -1: by cooling, 0: neither, as at power-on). A condition's bias is
carried to the midline with the product's declared typical hysteresis:

    correction = -h_typ / 2 x state,   u(correction) = sigma_h / 2 x |state|   (k=1)

The correction's error is the part's own (h - h_typ) / 2 x state: the same unknown h at every
condition, so its uncertainty is fully correlated between the conditions (the fit carries it as
such: procedures.analysis.temp_supply_fit). A part whose h lies far outside the declared spread
can only be seen by a condition reached from the other side (the procedure's
conditions.revisit_c): with biases from both sides the fit leaves h to the data (a common
term of FREE_DPS, in effect a free parameter) and `own_hysteresis` measures the part's h
against the declared spread.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_supply_fit import (
    ConditionMeasurement,
    condition_table,
    weighted_lsq,
)


class PlayOperator:
    """The hysteresis state of one part from its die temperature readings, in time order.

    Each block of readings is taken as its mean (the die moves far less than w within a block
    of the stream, and the mean keeps the sensor's noise out of the state)."""

    def __init__(self, width_c: float) -> None:
        if not width_c > 0:
            raise AnalysisError(f"hysteresis width {width_c} C: must be positive")
        self.width_c = width_c
        self._centre_c: float | None = None
        self._last_c: float | None = None

    def follow(self, temp_c: ArrayLike) -> None:
        """Advance over a block of die temperature readings (C); NaN readings are skipped."""
        arr = np.asarray(temp_c, dtype=np.float64)
        arr = arr[np.isfinite(arr)]
        if not arr.size:
            return
        t = float(arr.mean())
        if self._centre_c is None:
            self._centre_c = t  # power-on: centred, neither heated nor cooled
        w = self.width_c
        self._centre_c = min(max(self._centre_c, t - w), t + w)
        self._last_c = t

    @property
    def state(self) -> float | None:
        """+1 after heating by 2 w or more, -1 after cooling, between them on a reversal;
        None before any reading."""
        if self._centre_c is None or self._last_c is None:
            return None
        return (self._last_c - self._centre_c) / self.width_c


@dataclass(frozen=True)
class HysteresisCorrection:
    """What a condition's bias is corrected by (added to the measured bias), k=1."""

    state: float
    correction_dps: float
    u_correction_dps: float  # correlated between the conditions of one part (the same h)
    # what the fit carries as the error common to the conditions, signed by the state:
    # u_correction_dps's, or FREE_DPS x state when the fit leaves h to the data
    u_common_dps: float


def correction(state: float, hysteresis_dps: float, u_hysteresis_dps: float
               ) -> HysteresisCorrection:
    """The correction that carries a bias measured in `state` to the hysteresis midline,
    with an h and its k=1 uncertainty (the product's typical h and spread)."""
    s = min(max(float(state), -1.0), 1.0)
    return HysteresisCorrection(
        state=s,
        correction_dps=-0.5 * hysteresis_dps * s,
        u_correction_dps=0.5 * u_hysteresis_dps * abs(s),
        u_common_dps=0.5 * u_hysteresis_dps * s,
    )




BOTH_SIDES = 0.5  # a design has both sides when its states reach -0.5 and +0.5
# k=1, deg/s: the common term that leaves the hysteresis to the data (many times any bias)
FREE_DPS = 10.0


def both_sides(states: Sequence[float]) -> bool:
    """Do the conditions hold biases reached from both sides of the hysteresis?"""
    return bool(states) and min(states) <= -BOTH_SIDES and max(states) >= BOTH_SIDES


@dataclass(frozen=True)
class OwnHysteresis:
    """The part's own hysteresis, fitted with the first-order bias model to conditions
    reached from both sides, against the product's declared typical value and spread."""

    hysteresis_dps: float
    u_hysteresis_dps: float  # k=1
    typical_dps: float
    normalised: float  # (own - typical) / sqrt(u^2 + sigma^2): ~N(0, 1) for a typical part
    limit: float = 3.0

    @property
    def beyond_typical(self) -> bool:
        return abs(self.normalised) > self.limit

    @classmethod
    def against(cls, h: float, u_h: float, typical: tuple[float, float]) -> OwnHysteresis:
        """A part's own h (u k = 1) against the product's typical (h, sigma)."""
        spread = math.hypot(u_h, typical[1])
        return cls(h, u_h, typical[0], (h - typical[0]) / spread if spread > 0 else 0.0)


def own_hysteresis(conditions: Sequence[ConditionMeasurement], states: Sequence[float],
                   typical: tuple[float, float], reference: tuple[float, float]
                   ) -> OwnHysteresis:
    """Fit b0 + bT dT + bV dV + (h / 2) state to the measured (uncorrected) biases;
    `typical` is the product's (h, sigma), `reference` (T0, V0). AnalysisError when the
    conditions do not reach both sides or cannot separate h from the other terms."""
    if not both_sides(states):
        raise AnalysisError("the part's own hysteresis needs conditions reached from both "
                            "sides: add a revisit (conditions.revisit_c)")
    arr = condition_table(conditions)
    design = np.column_stack([np.ones(len(arr)), arr[:, 0] - reference[0],
                              arr[:, 1] - reference[1], np.asarray(states, dtype=np.float64)])
    p, cov, _ = weighted_lsq(design, arr[:, 2], arr[:, 3], 1e12,
                             "the conditions cannot separate the hysteresis from the "
                             "temperature and supply terms")
    return OwnHysteresis.against(2.0 * float(p[3]), 2.0 * math.sqrt(float(cov[3, 3])), typical)


def own_correction(state: float, own: OwnHysteresis) -> HysteresisCorrection:
    """The correction with the part's own h, the fit leaving h to the data."""
    c = correction(state, own.hysteresis_dps, own.u_hysteresis_dps)
    return HysteresisCorrection(c.state, c.correction_dps, c.u_correction_dps,
                                FREE_DPS * c.state)
