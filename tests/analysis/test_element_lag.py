"""procedures/analysis/element_lag.py: the element's temperature behind its sensor's."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.element_lag import element_at_windows, element_track


def test_on_a_steady_ramp_the_element_is_tau_times_the_rate_behind() -> None:
    t = np.arange(0.0, 300.0, 1.0)
    sensor = 25.0 + 0.05 * t
    e = element_track(t, sensor, 20.0)
    assert e == pytest.approx(sensor - 0.05 * 20.0, abs=1e-9)


def test_after_a_step_in_rate_the_lag_settles_with_tau() -> None:
    """Sensor at rest, then ramping: the element's exact first-order response."""
    t = np.arange(0.0, 200.0, 0.5)
    sensor = np.where(t < 50, 25.0, 25.0 + 0.1 * (t - 50))
    e = element_track(t, sensor, 20.0)
    after = t >= 50
    exact = 25.0 + 0.1 * ((t - 50) - 20.0 * (1 - np.exp(-(t - 50) / 20.0)))
    assert e[after] == pytest.approx(exact[after], abs=1e-9)
    assert e[~after] == pytest.approx(25.0)


def test_window_means_and_the_elements_rate() -> None:
    t = np.arange(0.0, 300.0, 1.0)
    sensor = 25.0 + 0.05 * t
    temps, rates = element_at_windows(t, sensor, 20.0, np.array([100.0, 200.0]), 3.0)
    assert temps == pytest.approx([29.0, 34.0], abs=1e-9)
    assert rates == pytest.approx([0.05, 0.05], abs=1e-9)
    same, _ = element_at_windows(t, sensor, 0.0, np.array([100.0]), 3.0)
    assert same == pytest.approx([30.0])
