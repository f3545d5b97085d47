"""The library's terms that couple the axes of a three-axis part (procedures/model/
cross_axis.py): their ids, specs and columns, searched on one axis of a three-axis part only
(a single-axis record gets no new candidate, so its false-alarm rate does not move)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from procedures.model import cross_axis, library
from procedures.model import effects as fx
from procedures.model.effect_spec import REGRESSOR_VOCABULARY
from procedures.model.gyro_model import first_order_model
from procedures.model.model_io import load_model, save_model
from procedures.model.trajectory import Segment, Trajectory

G = 9.80665


def _traj(axis: str = "", hot_faces: int = 6) -> Trajectory:
    """Axis `axis` of a part turned through its six faces (+x, -x, +y, -y, +z, -z) at 25 C,
    then through the first `hot_faces` of them at 45 C, the table at +-100 deg/s on each
    (or, without an axis, the same samples as a single-axis record)."""
    n = 100 * (6 + hot_faces)
    t = np.arange(n) * 0.1
    face = (np.arange(n) // 100) % 6
    hot = np.arange(n) >= 600
    table = np.where((np.arange(n) // 50) % 2 == 0, 100.0, -100.0)
    up = np.zeros((n, 3))
    for f in range(6):
        up[face == f, f // 2] = 1.0 if f % 2 == 0 else -1.0
    variables = {}
    if axis:
        variables = {"rate_x": table * up[:, 0], "rate_z": table * up[:, 2],
                     **{f"accel_{a}": G * up[:, i] for i, a in enumerate("xyz")}}
    return Trajectory(time_s=t, gyro_dps=np.zeros(n), ref_rate_dps=np.zeros(n),
                      ref_angle_deg=np.zeros(n), temp_c=np.where(hot, 45.0, 25.0),
                      supply_v=np.full(n, 5.0), time_since_power_on_s=t,
                      segments=(Segment("plateau", 0.0, t[-1] + 1.0),), axis=axis,
                      axis_variables=variables)


def test_a_cross_term_names_the_axes_it_couples() -> None:
    drift = fx.check_effect_id("lib_yfromx_w_dT")
    assert drift.couples == ("y", "x")
    assert drift.regressors == ("rate_x", "temperature")
    assert set(drift.params) == {"coeff", "offset"} and drift.n_columns == 2
    assert fx.formula_of("lib_yfromx_w_dT", {"coeff": 5e-5, "offset": 0.0}).startswith(
        "couples y <- x: ")
    g2 = fx.check_effect_id("lib_zfromy_a2")
    assert g2.couples == ("z", "y") and g2.regressors == ("accel_y",)
    assert g2.params["coeff"] == "deg/s per (m/s^2)^2" and g2.n_columns == 4
    for spec in (drift, g2):
        assert set(spec.regressors) <= set(REGRESSOR_VOCABULARY)
    assert fx.check_effect_id("lib_dT2").couples == ()  # the single-axis library's: none
    for bad in ("lib_xfromx_a2", "lib_yfromw_w_dT"):
        with pytest.raises(ValueError):
            fx.check_effect_id(bad)


def test_cross_terms_are_searched_on_one_axis_of_a_three_axis_part_only() -> None:
    single, axis_y = _traj(), _traj("y")
    assert not any(cross_axis.is_cross_id(e) for e in library.spanned_ids(single))
    assert library.spanned_ids(single) == library.spanned_ids(single, library.candidate_ids())
    cross = [e for e in library.spanned_ids(axis_y) if cross_axis.is_cross_id(e)]
    assert cross == ["lib_yfromx_w_dT", "lib_yfromx_a2", "lib_yfromz_w_dT", "lib_yfromz_a2"]
    # hot on the x faces only: z's rate never meets a second temperature (w_z dT ~ w_z)
    assert cross_axis.candidate_ids(_traj("y", hot_faces=2)) == (
        "lib_yfromx_w_dT", "lib_yfromx_a2", "lib_yfromz_a2")
    # one face per axis: a_x^2 = g^2 + g a_y - g a_z there (what the fit's linear G holds)
    one_face = _traj("y")
    keep = np.isin((np.arange(one_face.n) // 100) % 6, (0, 3, 4))
    one_face = Trajectory(**{**{f: getattr(one_face, f)[keep] for f in (
        "time_s", "gyro_dps", "ref_rate_dps", "ref_angle_deg", "temp_c", "supply_v",
        "time_since_power_on_s")}, "segments": one_face.segments, "axis": "y",
        "axis_variables": {k: v[keep] for k, v in one_face.axis_variables.items()}})
    assert cross_axis.candidate_ids(one_face) == ("lib_yfromx_w_dT", "lib_yfromz_w_dT")


def test_cross_term_columns_and_parameters() -> None:
    traj = _traj("y")
    cols = library.columns("lib_yfromx_w_dT", traj)
    np.testing.assert_array_equal(cols[:, 0], traj.axis_variables["rate_x"])
    np.testing.assert_array_equal(cols[:, 1], traj.axis_variables["rate_x"] * traj.dtemp_c)
    cols = library.columns("lib_yfromz_a2", traj)
    assert cols.shape == (traj.n, 4)
    np.testing.assert_array_equal(cols[:, 3], traj.axis_variables["accel_z"] ** 2)
    for e, coefs in (("lib_yfromx_w_dT", [1e-3, 5e-5]), ("lib_yfromz_a2", [1, 2, 3, 4e-3])):
        params, unc = library.to_params(e, np.array(coefs), np.eye(len(coefs)) * 1e-8)
        assert set(params) == set(fx.check_effect_id(e).params) == set(unc)
        np.testing.assert_allclose(library.to_coefficients(e, params), coefs)
    assert library.to_params("lib_yfromx_w_dT", np.array([1e-3, 5e-5]), np.eye(2))[0] == {
        "offset": 1e-3, "coeff": 5e-5}


def test_a_model_holding_a_cross_term_is_saved_and_read_back(tmp_path: Path) -> None:
    model = first_order_model().with_effect(
        "lib_yfromx_w_dT", {"coeff": 2e-5, "offset": -2e-4}).with_effect(
        "lib_yfromz_a2", {"coeff": 3e-4, "offset_x": 1e-3, "offset_y": 0.0, "offset_z": 0.0})
    back = load_model(save_model(model, tmp_path / "model.yaml"))
    assert back.effects == model.effects


def test_a_cross_term_on_a_record_it_does_not_fit_is_refused_in_words() -> None:
    for traj, term in ((_traj(), "lib_yfromx_w_dT"), (_traj("x"), "lib_yfromz_a2")):
        with pytest.raises(ValueError, match="couples axis y to axis"):
            library.columns(term, traj)
