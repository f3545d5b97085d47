"""First-order low-pass (sensor lag) applied to sampled signals.

Ramp-invariant discretisation: exact for an input that is linear between samples, so a lag
of a few milliseconds is modelled correctly at a sample period of the same order. The
filter restarts at gaps in the sampling (more than 3 sample periods), as the part's output
is only recorded in windows.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

FloatArray = NDArray[np.float64]


_last_runs: list[tuple[FloatArray, list[tuple[int, int]]]] = []  # the last record's


def contiguous_runs(time_s: FloatArray) -> list[tuple[int, int]]:
    """Index ranges [start, stop) of runs of regularly sampled data (the last array's kept:
    the lag filter asks again for every trial time constant)."""
    if _last_runs and _last_runs[0][0] is time_s:
        return list(_last_runs[0][1])
    runs = _contiguous_runs(time_s)
    _last_runs[:] = [(time_s, runs)]
    return list(runs)


def _contiguous_runs(time_s: FloatArray) -> list[tuple[int, int]]:
    dt = np.diff(time_s)
    if dt.size == 0:
        return [(0, time_s.size)]
    step = float(np.median(dt))
    breaks = np.flatnonzero(dt > 3.0 * step) + 1
    edges = [0, *breaks.tolist(), time_s.size]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def lag_filter(values: FloatArray, time_s: FloatArray, tau_s: float) -> FloatArray:
    """Pass `values` (n,) or (n, k) through a first-order lag of time constant `tau_s`.

    Each run starts settled on its first value (the part had been steady before recording).
    """
    if tau_s <= 0:
        return np.array(values, dtype=float, copy=True)
    x = np.asarray(values, dtype=float)
    out = np.empty_like(x)
    for a, b in contiguous_runs(time_s):
        seg = x[a:b]
        if b - a < 2:
            out[a:b] = seg
            continue
        dt = _median_step(time_s, a, b)
        alpha = float(np.exp(-dt / tau_s))
        g = (tau_s / dt) * (1.0 - alpha)
        b0 = 1.0 - g
        b1 = g - alpha
        num = np.array([b0, b1])
        den = np.array([1.0, -alpha])
        # initial state so the filter starts settled on the first input value
        zi_unit = b1 + alpha  # filter state when settled on a unit input
        zi = np.multiply.outer(np.array([zi_unit]), seg[0])
        out[a:b], _ = lfilter(num, den, seg, axis=0, zi=zi)
    return out


_last_steps: list[tuple[FloatArray, dict[tuple[int, int], float]]] = []


def _median_step(time_s: FloatArray, a: int, b: int) -> float:
    """Median sample step of time_s[a:b] (kept per run of the last array)."""
    if not (_last_steps and _last_steps[0][0] is time_s):
        _last_steps[:] = [(time_s, {})]
    steps = _last_steps[0][1]
    if (a, b) not in steps:
        steps[(a, b)] = float(np.median(np.diff(time_s[a:b])))
    return steps[(a, b)]
