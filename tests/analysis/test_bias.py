from __future__ import annotations

import math

import numpy as np
import pytest

from procedures.analysis.allan import NoiseModel, overlapping_adev
from procedures.analysis.bias import (
    estimate_bias,
    require_averaging_time_s,
    required_averaging_time_s,
    window_mean,
)
from procedures.analysis.errors import AnalysisError
from tests.analysis.synth import gyro_noise

FS = 100.0


def test_white_noise_uncertainty_is_sigma_over_sqrt_n() -> None:
    rng = np.random.default_rng(1)
    est = estimate_bias(8.6 + 0.1 * rng.standard_normal(2000), FS)
    assert est.bias_correction_dps == -est.bias_dps
    assert est.u_bias_dps == pytest.approx(0.1 / math.sqrt(2000), rel=0.05)


def test_k2_interval_covers_the_true_bias_93_to_97_percent() -> None:
    rng = np.random.default_rng(7)
    trials, n, truth = 1000, 400, 8.6
    hits = 0
    for _ in range(trials):
        est = estimate_bias(truth + 0.1 * rng.standard_normal(n), FS)
        hits += abs(est.bias_dps - truth) <= est.u_bias_dps_k2
    assert 0.93 <= hits / trials <= 0.97, hits / trials


def test_correlated_noise_uncertainty_is_the_allan_deviation_at_the_window_length() -> None:
    """With flicker noise sigma/sqrt(N) understates; the Allan-based u matches what window
    means really scatter by (the ADEV at T, measured on a long record)."""
    rng = np.random.default_rng(2)
    window_s = 60.0
    long = gyro_noise(rng, int(FS * 7200), FS, arw_deg_per_sqrt_h=0.3,
                      bias_instability_deg_per_h=25.0)
    truth_adev = overlapping_adev(long, FS, [window_s]).adev_dps[0]
    n = int(window_s * FS)
    wm = window_mean(long[:n], FS)
    assert wm.naive_u_dps < 0.3 * truth_adev  # sigma / sqrt(N) is several times too small
    # one 60 s window fixes its own noise model to about 20 % (seen over seeds 0-5)
    assert wm.u_mean_dps == pytest.approx(truth_adev, rel=0.25)
    # with the part's known noise model the uncertainty follows it exactly
    model = NoiseModel.from_datasheet(0.3, 25.0)
    assert window_mean(long[:n], FS, noise=model).u_mean_dps == pytest.approx(
        float(model.adev_dps(window_s)), rel=1e-12)


def test_averaging_time_for_a_requested_accuracy() -> None:
    model = NoiseModel.from_datasheet(arw_deg_per_sqrt_h=0.6)
    t = required_averaging_time_s(model, bias_accuracy_dps=0.002, k=2.0)
    assert t == pytest.approx((0.01 / 0.001) ** 2)  # N^2 / (accuracy / k)^2
    # and a simulated window of that length scatters by accuracy / k
    rng = np.random.default_rng(5)
    n = int(t * FS)
    means = (0.1 * rng.standard_normal((400, n))).mean(axis=1)
    assert np.std(means) == pytest.approx(0.001, rel=0.1)


def test_accuracy_below_the_flicker_floor_is_unreachable() -> None:
    model = NoiseModel.from_datasheet(arw_deg_per_sqrt_h=0.6, bias_instability_deg_per_h=20.0)
    floor = 0.664 * 20.0 / 3600.0
    assert math.isinf(required_averaging_time_s(model, floor, k=1.0))
    assert math.isfinite(required_averaging_time_s(model, 1.5 * floor, k=1.0))
    with pytest.raises(AnalysisError, match="relax the request"):
        require_averaging_time_s(model, floor, k=1.0)


def test_estimate_carries_its_averaging_time_helper() -> None:
    rng = np.random.default_rng(6)
    est = estimate_bias(0.1 * rng.standard_normal(3000), FS)
    assert est.averaging_time_s(0.002) == pytest.approx(100.0, rel=0.1)


def test_short_window_is_refused_with_a_clear_message() -> None:
    with pytest.raises(AnalysisError, match="record longer"):
        estimate_bias([1.0, 2.0, 3.0], FS)


def test_stuck_output_is_refused() -> None:
    with pytest.raises(AnalysisError, match="stuck"):
        estimate_bias(np.full(500, 8.6), FS)
