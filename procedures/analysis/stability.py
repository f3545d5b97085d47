"""Thermal stability of a die temperature record: the criterion the `thermal` step judges.

`judge_stability` judges the last window of a record (slope of a straight-line fit and the
peak-to-peak of one-second means). `judge_span` judges every window across a longer span
(the stability window judged after the measurement it overlapped). `change_settles` says
whether a predicted self-heating change stays within the criterion (no wait at a supply
change). Pure functions, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class StabilityVerdict:
    stable: bool
    slope_c_per_min: float
    band_c: float
    mean_c: float
    span_s: float


def judge_stability(
    time_s: NDArray[np.float64],
    temp_c: NDArray[np.float64],
    window_s: float,
    slope_c_per_min: float,
    band_c: float,
    target_c: float | None = None,
    tolerance_c: float | None = None,
) -> StabilityVerdict:
    """Is the last `window_s` of a die temperature record stable? (needs a full window)."""
    if time_s.size < 3 or time_s[-1] - time_s[0] < window_s * 0.98:
        return StabilityVerdict(
            False,
            float("nan"),
            float("nan"),
            float("nan"),
            float(time_s[-1] - time_s[0]) if time_s.size else 0.0,
        )
    sel = time_s >= time_s[-1] - window_s
    t, y = time_s[sel], temp_c[sel]
    slope = float(np.polyfit(t - t[0], y, 1)[0]) * 60.0
    # peak-to-peak of 1 s means: the band is about drift, not sensor noise
    bins = np.floor(t - t[0]).astype(np.int64)
    counts = np.bincount(bins)
    sums = np.bincount(bins, weights=y)
    means = sums[counts > 0] / counts[counts > 0]
    band = float(np.ptp(means))
    mean = float(y.mean())
    ok = abs(slope) <= slope_c_per_min and band <= band_c
    if ok and target_c is not None and tolerance_c is not None:
        ok = abs(mean - target_c) <= tolerance_c
    return StabilityVerdict(ok, slope, band, mean, float(t[-1] - t[0]))


def judge_span(
    time_s: NDArray[np.float64],
    temp_c: NDArray[np.float64],
    window_s: float,
    step_s: float,
    slope_c_per_min: float,
    band_c: float,
    target_c: float | None = None,
    tolerance_c: float | None = None,
) -> StabilityVerdict:
    """Every `window_s` window across the record, one ending every `step_s` and the last at
    its end: the first that fails, else the one with the largest |slope| (the span is stable
    only if every window is). A record shorter than one window is not stable."""
    if time_s.size < 3 or time_s[-1] - time_s[0] < window_s * 0.98:
        return judge_stability(time_s, temp_c, window_s, slope_c_per_min, band_c)
    ends = list(np.arange(time_s[0] + window_s, time_s[-1], step_s)) + [time_s[-1]]
    worst: StabilityVerdict | None = None
    for end in ends:
        sel = (time_s <= end) & (time_s >= end - window_s - 1e-9)
        v = judge_stability(time_s[sel], temp_c[sel], window_s, slope_c_per_min, band_c,
                            target_c, tolerance_c)
        if not v.stable and v.span_s >= window_s * 0.98:
            return v
        if worst is None or not math.isfinite(worst.slope_c_per_min) or abs(
            v.slope_c_per_min
        ) > abs(worst.slope_c_per_min):
            worst = v
    assert worst is not None
    span = float(time_s[-1] - time_s[0])
    return StabilityVerdict(worst.stable, worst.slope_c_per_min, worst.band_c,
                            float(np.mean(temp_c)), span)


def change_settles(
    change_c: float, heat_tau_s: float, slope_c_per_min: float, band_c: float
) -> bool:
    """Does a predicted first-order self-heating change of `change_c` (time constant
    `heat_tau_s`) meet the stability criterion while it happens: the whole change within the
    band, and its steepest rate, at its start (change / tau), within the slope limit?"""
    if not math.isfinite(change_c) or heat_tau_s <= 0:
        return False
    return abs(change_c) <= band_c and abs(change_c) / heat_tau_s * 60.0 <= slope_c_per_min
