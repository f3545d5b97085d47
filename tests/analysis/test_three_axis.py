"""The three-axis fit against synthetic windows generated from the contract's model directly
(raw = M^-1 D w + b + G a + noise), apart from the analysis code."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.three_axis import Window, fit_three_axis

G_MPS2 = 9.80665
RATE_DPS = 100.0
U_MEAN_DPS = 0.004
FACES_ALL = ("+z", "-z", "+x", "-x", "+y", "-y")
FACES_FEW = ("+y", "+x", "+z")
CONDITIONS = ((25.0, 4.75), (25.0, 5.25), (45.0, 5.25), (45.0, 4.75))


def _axis(face: str) -> np.ndarray:
    e = np.zeros(3)
    e["xyz".index(face[1])] = 1.0 if face[0] == "+" else -1.0
    return e


def random_truth(rng: np.random.Generator) -> dict[str, np.ndarray]:
    m = np.eye(3) + rng.uniform(-0.02, 0.02, (3, 3))
    return {
        "bias_dps": rng.uniform(-2, 2, 3),
        "matrix": m,
        "g_sensitivity_dps_per_mps2": rng.uniform(-0.01, 0.01, (3, 3)),
        "bias_temp_coeff_dps_per_c": rng.uniform(-0.01, 0.01, 3),
        "bias_supply_coeff_dps_per_v": rng.uniform(-0.05, 0.05, 3),
        "scale_temp_coeff_per_c": rng.uniform(-3e-4, 3e-4, 3),
        "scale_supply_coeff_per_v": rng.uniform(-2e-3, 2e-3, 3),
    }


def synth_windows(
    truth: dict[str, np.ndarray], rng: np.random.Generator, conditions=CONDITIONS
) -> list[Window]:
    out = []
    for k, (temp_c, supply_v) in enumerate(conditions):
        die_c = temp_c + 3.0 + rng.normal(0, 0.2)  # self-heating: the die is not the setpoint
        dt, dv = die_c - 25.0, supply_v - 5.0
        s = np.linalg.inv(truth["matrix"]) @ np.diag(
            1 + truth["scale_temp_coeff_per_c"] * dt + truth["scale_supply_coeff_per_v"] * dv)
        b = (truth["bias_dps"] + truth["bias_temp_coeff_dps_per_c"] * dt
             + truth["bias_supply_coeff_dps_per_v"] * dv)
        for face in FACES_ALL if k == 0 else FACES_FEW:
            a = G_MPS2 * _axis(face) + rng.normal(0, 0.002, 3)
            for r in (0.0, RATE_DPS, -RATE_DPS):
                raw = s @ (r * _axis(face)) + b + truth["g_sensitivity_dps_per_mps2"] @ a
                raw = raw + rng.normal(0, U_MEAN_DPS, 3)
                out.append(Window(face, r, tuple(raw), (U_MEAN_DPS,) * 3, tuple(a),
                                  die_c, supply_v, f"c{k}"))
    return out


NAMES = ("bias_dps", "matrix", "g_sensitivity_dps_per_mps2", "bias_temp_coeff_dps_per_c",
         "bias_supply_coeff_dps_per_v", "scale_temp_coeff_per_c", "scale_supply_coeff_per_v")


def test_one_part_within_k2_of_truth() -> None:
    rng = np.random.default_rng(18)
    truth = random_truth(rng)
    cal = fit_three_axis(synth_windows(truth, rng))
    assert cal.temp_supply_fitted
    for name in NAMES:
        err = np.abs(cal.value(name) - truth[name])
        # 4 k=2 widths: one part, 42 numbers; a wrong model is off by orders of magnitude
        assert np.all(err <= 2 * cal.uncertainty_k2(name)), name
    assert 0.2 < cal.chi2 / cal.dof < 3.0


def test_coverage_over_many_parts_is_near_95_percent() -> None:
    rng = np.random.default_rng(7)
    inside = {name: [] for name in NAMES}
    for _ in range(150):
        truth = random_truth(rng)
        cal = fit_three_axis(synth_windows(truth, rng))
        for name in NAMES:
            err = np.abs(cal.value(name) - truth[name])
            inside[name].extend((err <= cal.uncertainty_k2(name)).ravel().tolist())
    for name in NAMES:
        assert 0.92 <= np.mean(inside[name]) <= 0.98, (name, np.mean(inside[name]))


def test_reference_condition_only_fits_b_m_g() -> None:
    rng = np.random.default_rng(3)
    truth = random_truth(rng)
    for key in NAMES[3:]:
        truth[key] = np.zeros(3)
    cal = fit_three_axis(synth_windows(truth, rng, conditions=((25.0, 5.0),)))
    assert not cal.temp_supply_fitted and cal.notes
    for name in NAMES[:3]:
        assert np.all(np.abs(cal.value(name) - truth[name]) <= 2 * cal.uncertainty_k2(name))
    assert np.isnan(cal.uncertainty_k2("scale_temp_coeff_per_c")).all()


def test_missing_axis_rotation_is_refused_with_advice() -> None:
    rng = np.random.default_rng(4)
    windows = [w for w in synth_windows(random_truth(rng), rng)
               if not (w.face[1] == "y" and w.table_rate_dps != 0)]
    with pytest.raises(AnalysisError, match="about axis y"):
        fit_three_axis(windows)


def test_static_faces_missing_is_refused() -> None:
    rng = np.random.default_rng(5)
    windows = [w for w in synth_windows(random_truth(rng), rng) if w.face.startswith("+")]
    with pytest.raises(AnalysisError, match="six faces"):
        fit_three_axis(windows)


def test_bad_window_is_refused() -> None:
    with pytest.raises(AnalysisError, match="NaN"):
        Window("+x", 0.0, (float("nan"), 0, 0), (0.01,) * 3, (9.8, 0, 0), 25.0, 5.0)
    with pytest.raises(AnalysisError, match="not one of"):
        fit_three_axis([Window("up", 0.0, (0, 0, 0), (0.01,) * 3, (9.8, 0, 0), 25.0, 5.0)])
