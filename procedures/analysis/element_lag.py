"""The sensing element's temperature from its sensor's: a first-order lag of time constant tau.

Exact for a sensor temperature that changes linearly between its samples (first-order hold):
e(t1) = d1 - r tau + (e0 - d0 + r tau) exp(-(t1 - t0) / tau), r the slope between the two
samples (docs/simulated-bench.md gives the same closed form for the bench's parts). The
element's rate is (d - e) / tau. The track starts on a steady ramp: the element tau times
the sensor's first rate (over its first START_S) behind it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
START_S = 10.0


def element_track(time_s: F64, sensor_c: F64, tau_s: float) -> F64:
    """The element's temperature at the track's times (tau 0: the sensor's)."""
    if tau_s <= 0 or time_s.size < 2:
        return sensor_c.copy()
    out = np.empty_like(sensor_c)
    first = time_s <= time_s[0] + START_S
    slope = float(np.polyfit(time_s[first] - time_s[0], sensor_c[first], 1)[0]) \
        if np.count_nonzero(first) >= 3 else 0.0
    e = float(sensor_c[0]) - tau_s * slope
    out[0] = e
    for i in range(1, time_s.size):
        dt = float(time_s[i] - time_s[i - 1])
        d0, d1 = float(sensor_c[i - 1]), float(sensor_c[i])
        r = (d1 - d0) / dt if dt > 0 else 0.0
        e = d1 - r * tau_s + (e - d0 + r * tau_s) * float(np.exp(-dt / tau_s))
        out[i] = e
    return out


def element_at_windows(time_s: F64, sensor_c: F64, tau_s: float, centre_s: F64,
                       half_s: float) -> tuple[F64, F64]:
    """The element's mean temperature and mean rate (C/s) over windows centre +/- half."""
    e = element_track(time_s, sensor_c, tau_s)
    rate = (sensor_c - e) / tau_s if tau_s > 0 else np.gradient(sensor_c, time_s)
    temps = np.empty_like(centre_s)
    rates = np.empty_like(centre_s)
    for i, c in enumerate(centre_s):
        sel = (time_s >= c - half_s) & (time_s <= c + half_s)
        if not np.any(sel):
            sel = np.abs(time_s - c) == np.min(np.abs(time_s - c))
        temps[i] = float(np.mean(e[sel]))
        rates[i] = float(np.mean(rate[sel]))
    return temps, rates
