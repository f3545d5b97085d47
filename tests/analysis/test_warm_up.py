"""Warm-up time from a fitted exponential, against synthetic truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.warm_up import warm_up_time

FS = 50.0


def _trace(amp: float, tau: float, record_s: float, noise: float, seed: int, t0: float = 2.0):
    rng = np.random.default_rng(seed)
    t = np.arange(t0, record_s, 1.0 / FS)
    return t, 0.3 + amp * np.exp(-t / tau) + noise * rng.standard_normal(t.size)


def test_noise_free_transient_gives_the_analytic_time() -> None:
    t, y = _trace(0.2, 60.0, 600.0, 0.0, 0)
    w = warm_up_time(t, y + 1e-9 * np.sin(t), band_dps=0.01)
    assert w.resolved and w.settled_in_record
    assert w.warm_up_time_s == pytest.approx(60.0 * math.log(0.2 / 0.01), rel=1e-3)
    assert w.final_bias_dps == pytest.approx(0.3, abs=1e-6)


@pytest.mark.parametrize(("amp", "tau"), [(0.2, 60.0), (-0.1, 30.0), (0.5, 120.0)])
def test_noisy_transients_k2_interval_covers_the_truth(amp: float, tau: float) -> None:
    band = 0.01
    truth = tau * math.log(abs(amp) / band)
    hits, trials = 0, 40
    for seed in range(trials):
        t, y = _trace(amp, tau, 8 * tau, 0.05, seed)
        w = warm_up_time(t, y, band)
        hits += abs(w.warm_up_time_s - truth) <= 2 * w.u_warm_up_time_s
        assert abs(w.warm_up_time_s - truth) < 0.25 * truth
    assert hits / trials >= 0.85


def test_a_part_without_transient_is_settled_at_power_on() -> None:
    t, y = _trace(0.0, 60.0, 300.0, 0.05, 1)
    w = warm_up_time(t, y, band_dps=0.01)
    assert w.warm_up_time_s == 0.0 and w.u_warm_up_time_s == 0.0


def test_a_transient_longer_than_the_record_is_flagged() -> None:
    t, y = _trace(1.0, 100.0, 200.0, 0.005, 2)
    w = warm_up_time(t, y, band_dps=0.001)
    assert w.warm_up_time_s > w.record_end_s and not w.settled_in_record


@pytest.mark.parametrize(
    ("t", "y", "band", "match"),
    [(np.arange(10.0), np.zeros(10), 0.01, "at least 32"),
     (np.arange(100.0), np.zeros(100), 0.0, "positive"),
     (np.arange(100.0), np.zeros(99), 0.01, "same length")],
)
def test_bad_input_is_refused(t, y, band, match) -> None:
    with pytest.raises(AnalysisError, match=match):
        warm_up_time(t, y, band)
