"""The stop method's uncertainty when the bias drifts (bias instability) between the leading
rest and the moves: the covariance of the angle errors, and coverage on synthetic records."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.allan import NoiseModel
from procedures.analysis.stop_method import analyze_stop_method, angle_error_covariance
from tests.analysis.synth import gyro_noise, raised_cosine

WHITE = NoiseModel(arw_deg_per_sqrt_s=0.01)
FLICKER = NoiseModel(bias_instability_dps=0.004)
RRW = NoiseModel(rrw_dps_per_sqrt_s=1e-4)


@pytest.mark.parametrize("noise", [WHITE, FLICKER, RRW], ids=["white", "flicker", "rrw"])
@pytest.mark.parametrize("t_s", [0.5, 4.0, 40.0])
def test_move_next_to_a_window_of_its_length_has_twice_the_allan_variance(
    noise: NoiseModel, t_s: float
) -> None:
    # mean over [T, 2T] minus mean over [0, T]: the Allan variance's own definition
    cov = angle_error_covariance(noise, (0.0, t_s), [(t_s, 2.0 * t_s)])
    assert cov[0, 0] == pytest.approx(2.0 * float(noise.avar_dps2(t_s)) * t_s**2, rel=1e-4)


def test_white_noise_is_the_move_noise_plus_a_common_bias_term() -> None:
    moves = [(5.0, 9.0), (20.0, 23.5)]
    cov = angle_error_covariance(WHITE, (0.0, 5.0), moves)
    n2 = WHITE.arw_deg_per_sqrt_s**2
    dur = np.array([4.0, 3.5])
    assert cov == pytest.approx(n2 * (np.diag(dur) + np.outer(dur, dur) / 5.0), rel=1e-12)


def test_bias_drift_grows_with_the_distance_from_the_bias_window() -> None:
    near, far = angle_error_covariance(FLICKER, (0.0, 5.0), [(5.0, 9.0), (40.0, 44.0)]).diagonal()
    assert far > 1.5 * near  # the drift the white-noise budget left out
    white = angle_error_covariance(WHITE, (0.0, 5.0), [(5.0, 9.0), (40.0, 44.0)]).diagonal()
    assert white[1] == pytest.approx(white[0])


def _z_scores(noise: NoiseModel | None, trials: int) -> np.ndarray:
    """(scale correction - truth) / u on records with strong bias instability, the second
    move 14 s after the first as on the station's bench."""
    rng = np.random.default_rng(11)
    fs = 100.0
    t = np.arange(0.0, 28.0, 1.0 / fs)
    motion = raised_cosine(t, 6.0, 3.5, 90.0) + raised_cosine(t, 20.0, 3.5, -90.0)
    z = []
    for _ in range(trials):
        y = 2.0 + motion + gyro_noise(rng, t.size, fs, 0.3, 30.0)
        r = analyze_stop_method(t, y, 90.0, 0.0, noise=noise)
        assert r.scale_correction is not None and r.u_scale_correction is not None
        z.append((r.scale_correction - 1.0) / r.u_scale_correction)
    return np.asarray(z)


def test_part_noise_model_gives_standard_scores_with_unit_spread() -> None:
    z = _z_scores(NoiseModel.from_datasheet(0.3, 30.0), 400)
    assert 0.88 < z.std(ddof=1) < 1.12
    assert abs(z.mean()) < 0.15
    assert np.mean(np.abs(z) > 2.0) < 0.08


def test_leading_rest_alone_understates_the_uncertainty_under_bias_instability() -> None:
    # the leading rest's own noise fit sees white noise only: the z-scores spread far wider
    z = _z_scores(None, 150)
    assert z.std(ddof=1) > 1.8
