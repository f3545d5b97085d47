"""The Ferraris multi-position analysis on simulated hand-turned sessions (tests/analysis/
hand_turned.py, written apart from the analysis): truth recovered within k=2, and the same
answer as imucal's FerrarisCalibration on the same data."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.multi_position import (
    SECTIONS,
    MultiPositionResult,
    analyze_multi_position,
)
from tests.analysis.hand_turned import Session, hand_turned_session, random_truth


def _analyse(s: Session, accel: bool = True, **kw: float) -> MultiPositionResult:
    return analyze_multi_position(
        s.gyro_dps,
        s.sections,
        s.sample_rate_hz,
        rotation_deg=s.rotation_deg,
        accel_mps2=s.accel_mps2 if accel else None,
        **kw,
    )


def test_noise_free_session_gives_the_truth_exactly_despite_tilted_faces() -> None:
    rng = np.random.default_rng(10)
    truth = random_truth(rng)
    s = hand_turned_session(rng, truth, gyro_noise_dps=0.0, accel_noise_mps2=0.0, tilt_deg=3.0)
    r = _analyse(s)
    assert r.g_sensitivity_dps_per_mps2 is not None
    np.testing.assert_allclose(r.bias_dps, truth.bias_dps, atol=1e-10)
    np.testing.assert_allclose(r.matrix, truth.matrix, atol=1e-10)
    np.testing.assert_allclose(r.g_sensitivity_dps_per_mps2, truth.g_sensitivity, atol=1e-12)
    np.testing.assert_allclose(r.u_bias_dps, 0.0)


def test_clockwise_rotations_with_a_negative_angle() -> None:
    rng = np.random.default_rng(11)
    truth = random_truth(rng)
    s = hand_turned_session(rng, truth, rotation_deg=-720.0, gyro_noise_dps=0.0,
                            accel_noise_mps2=0.0)
    np.testing.assert_allclose(_analyse(s).matrix, truth.matrix, atol=1e-10)


def test_truth_within_k2_over_many_sessions() -> None:
    """Coverage of the stated k=2 uncertainties: near 95 % for b, M and G (not 100 %: the
    uncertainties are not inflated either), and the errors themselves small."""
    rng = np.random.default_rng(12)
    z: dict[str, list[float]] = {"b": [], "M": [], "G": []}
    for _ in range(40):
        truth = random_truth(rng)
        r = _analyse(hand_turned_session(rng, truth))
        assert r.g_sensitivity_dps_per_mps2 is not None
        assert r.u_g_sensitivity_dps_per_mps2 is not None
        z["b"] += list((r.bias_dps - truth.bias_dps) / r.u_bias_dps)
        z["M"] += list(((r.matrix - truth.matrix) / r.u_matrix).ravel())
        g_err = r.g_sensitivity_dps_per_mps2 - truth.g_sensitivity
        z["G"] += list((g_err / r.u_g_sensitivity_dps_per_mps2).ravel())
        assert np.abs(r.matrix - truth.matrix).max() < 5e-4  # 0.05 % scale / 0.03 deg
    for name, values in z.items():
        coverage = float(np.mean(np.abs(values) <= 2.0))
        assert 0.90 <= coverage <= 0.99, (name, coverage)
        assert 0.8 < float(np.std(values)) < 1.25, name


def test_without_accelerometer_g_is_not_estimated_and_b_m_still_covered() -> None:
    rng = np.random.default_rng(13)
    inside = []
    for _ in range(10):
        truth = random_truth(rng)
        r = _analyse(hand_turned_session(rng, truth), accel=False)
        assert r.g_sensitivity_dps_per_mps2 is None
        assert r.u_g_sensitivity_dps_per_mps2 is None
        inside += list(np.abs(r.bias_dps - truth.bias_dps) <= r.u_bias_dps_k2)
        inside += list((np.abs(r.matrix - truth.matrix) <= r.u_matrix_k2).ravel())
    assert np.mean(inside) >= 0.88


def test_rotation_angle_uncertainty_widens_m() -> None:
    rng = np.random.default_rng(14)
    s = hand_turned_session(rng, random_truth(rng))
    tight = _analyse(s)
    loose = _analyse(s, u_rotation_deg=1.0)
    # 1 deg in 360 is 0.28 %: the diagonal's u grows to about that
    assert np.all(np.diag(loose.u_matrix) > 0.002)
    assert np.all(np.diag(tight.u_matrix) < 0.001)


def test_missing_unknown_and_out_of_range_sections_are_named() -> None:
    rng = np.random.default_rng(15)
    s = hand_turned_session(rng, random_truth(rng))
    sections = dict(s.sections)
    del sections["y_a"]
    with pytest.raises(AnalysisError, match="y_a missing"):
        analyze_multi_position(s.gyro_dps, sections, 100.0)
    with pytest.raises(AnalysisError, match="unknown section.*x_rotation"):
        analyze_multi_position(s.gyro_dps, {**s.sections, "x_rotation": (0, 10)}, 100.0)
    n = s.gyro_dps.shape[0]
    with pytest.raises(AnalysisError, match="section z_rot: start .* outside"):
        analyze_multi_position(s.gyro_dps, {**s.sections, "z_rot": (n - 5, n + 5)}, 100.0)


def test_nan_and_shape_are_refused() -> None:
    rng = np.random.default_rng(16)
    s = hand_turned_session(rng, random_truth(rng))
    gyro = s.gyro_dps.copy()
    gyro[123, 1] = np.nan
    with pytest.raises(AnalysisError, match="sample 123, axis y"):
        analyze_multi_position(gyro, s.sections, 100.0)
    with pytest.raises(AnalysisError, match=r"\(n, 3\)"):
        analyze_multi_position(s.gyro_dps[:, :2], s.sections, 100.0)


def test_swapped_faces_and_wrong_rotation_sign_are_explained() -> None:
    rng = np.random.default_rng(17)
    s = hand_turned_session(rng, random_truth(rng))
    swapped = {**s.sections, "x_p": s.sections["x_a"], "x_a": s.sections["x_p"]}
    with pytest.raises(AnalysisError, match="x_p: the accelerometer reads gravity along -x"):
        analyze_multi_position(s.gyro_dps, swapped, 100.0, accel_mps2=s.accel_mps2)
    with pytest.raises(AnalysisError, match="give the angle as 360 deg"):
        analyze_multi_position(s.gyro_dps, s.sections, 100.0, rotation_deg=-360.0)


# -- agreement with imucal (PyPI imucal==2.6.0, test dependency) ------------------------------

def _imucal(s: Session) -> tuple[np.ndarray, np.ndarray, np.ndarray, object]:
    """imucal's b_g, M and K_ga on the session, mapped to this product's convention.

    imucal corrects w = R_g^-1 K_g^-1 (raw - b_g - K_ga a_cal), its K_g R_g being the
    integrated rotations over the expected angle, i.e. S: so M = R_g^-1 K_g^-1 = (K_g R_g)^-1.
    Its x_p is the face where the x accelerometer reads +g (our x axis up), so grav is +g;
    its expected_angle carries the sign of the rotation (its default -360 is clockwise),
    ours is right-hand positive: pass ours unchanged. It works in deg/s and m/s^2 as given.
    """
    imucal = pytest.importorskip("imucal")
    from imucal.ferraris_calibration import FerrarisSignalRegions

    regions = {}
    for name in SECTIONS:
        start, end = s.sections[name]
        regions["acc_" + name] = s.accel_mps2[start:end]
        regions["gyr_" + name] = s.gyro_dps[start:end]
    cal = imucal.FerrarisCalibration(grav=9.80665, expected_angle=s.rotation_deg)
    info = cal.compute(FerrarisSignalRegions(**regions), s.sample_rate_hz, "m/s^2", "deg/s")
    m = np.linalg.inv(info.R_g) @ np.linalg.inv(info.K_g)
    return np.asarray(info.b_g), m, np.asarray(info.K_ga), info


def test_mapping_to_imucal_on_an_ideal_session() -> None:
    """Noise-free, level faces: imucal's numbers, mapped, are the truth, and its correction of
    the raw samples equals M (raw - b - G a)."""
    rng = np.random.default_rng(20)
    truth = random_truth(rng)
    s = hand_turned_session(rng, truth, gyro_noise_dps=0.0, accel_noise_mps2=0.0, tilt_deg=0.0)
    b, m, g, info = _imucal(s)
    np.testing.assert_allclose(b, truth.bias_dps, atol=1e-10)
    np.testing.assert_allclose(m, truth.matrix, atol=1e-10)
    np.testing.assert_allclose(g, truth.g_sensitivity, atol=1e-12)
    start, end = s.sections["y_rot"]
    raw, acc = s.gyro_dps[start:end], s.accel_mps2[start:end]
    _, w_imucal = info.calibrate(acc, raw, "m/s^2", "deg/s")  # type: ignore[attr-defined]
    r = _analyse(s)
    assert r.g_sensitivity_dps_per_mps2 is not None
    w_ours = (raw - r.bias_dps - acc @ r.g_sensitivity_dps_per_mps2.T) @ r.matrix.T
    np.testing.assert_allclose(w_ours, w_imucal, atol=1e-9)
    assert np.abs(w_ours[:, 1]).max() > 100  # the rotation is in it


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_agrees_with_imucal_within_the_stated_uncertainty(seed: int) -> None:
    rng = np.random.default_rng(seed)
    s = hand_turned_session(rng, random_truth(rng))
    b, m, g, _ = _imucal(s)
    r = _analyse(s)
    assert r.u_g_sensitivity_dps_per_mps2_k2 is not None
    assert r.g_sensitivity_dps_per_mps2 is not None
    assert np.all(np.abs(b - r.bias_dps) <= r.u_bias_dps_k2)
    assert np.all(np.abs(m - r.matrix) <= r.u_matrix_k2)
    assert np.all(np.abs(g - r.g_sensitivity_dps_per_mps2) <= r.u_g_sensitivity_dps_per_mps2_k2)


def test_a_face_holding_part_of_a_turn_is_named_in_a_warning() -> None:
    rng = np.random.default_rng(18)
    s = hand_turned_session(rng, random_truth(rng))
    start, end = s.sections["y_a"]
    r = analyze_multi_position(s.gyro_dps, {**s.sections, "y_a": (start - 100, end)}, 100.0)
    assert len(r.warnings) == 1
    assert "section y_a is not static" in r.warnings[0]
    assert not _analyse(s).warnings


def test_a_bias_that_moves_during_the_session_is_flagged_and_u_b_widened() -> None:
    """A bias step between the x and y faces (a part still warming up): the three face pairs
    disagree beyond their noise, a warning says so, u(b) grows by the Birge ratio and then
    covers the step's effect; a steady session is not flagged."""
    rng = np.random.default_rng(19)
    truth = random_truth(rng)
    s = hand_turned_session(rng, truth)
    steady = _analyse(s)
    assert steady.bias_birge_ratio is None and steady.pairs_chi2 is not None
    assert steady.pairs_chi2 < 30
    step_at = s.sections["y_p"][0] - 50
    s.gyro_dps[step_at:] += np.array([0.03, -0.02, 0.01])
    r = _analyse(s)
    assert r.bias_birge_ratio is not None and r.bias_birge_ratio > 2
    assert any("pairs of opposite faces disagree" in w for w in r.warnings)
    np.testing.assert_allclose(r.u_bias_dps, steady.u_bias_dps * r.bias_birge_ratio, rtol=0.05)
    # the estimate is the faces' average of the moving bias: b plus 2/3 of the step
    expected = truth.bias_dps + np.array([0.02, -0.04 / 3, 0.01 * 2 / 3])
    assert np.all(np.abs(r.bias_dps - expected) <= r.u_bias_dps_k2)
