"""Unit tests of the model pieces: catalog, prediction, YAML, lag filter, Allan variance."""

from __future__ import annotations

import math

import allantools
import numpy as np
import pytest
from helpers_model import TINY, as_trajectory
from synth_gyro import Part, generate

from procedures.model.effects import CATALOG
from procedures.model.gyro_model import GyroModel, base_model, first_order_model
from procedures.model.lag import lag_filter
from procedures.model.model_io import load_model, save_model
from procedures.model.noise import overlapping_avar

CATALOG_IDS = {
    "k2_quadratic", "k3_cubic", "scale_asymmetry", "bias_temperature", "scale_temperature",
    "bias_supply", "scale_supply", "g_sensitivity_tilt", "sensor_lag", "warmup_drift",
}


def test_catalog_holds_the_pinned_ids_and_parameter_names() -> None:
    assert set(CATALOG) == CATALOG_IDS
    assert list(CATALOG["g_sensitivity_tilt"].params) == ["g_sens_dps_per_g", "tilt_deg",
                                                          "phase_deg"]
    assert list(CATALOG["warmup_drift"].params) == ["amplitude_dps", "tau_s"]
    assert set(first_order_model().effects) == {"bias_temperature", "scale_temperature",
                                                "bias_supply", "scale_supply"}
    assert base_model().effects == {}


def test_prediction_matches_the_design_equation() -> None:
    traj = as_trajectory(generate(Part(), 1, TINY))
    m = GyroModel(bias_dps=1.5, scale=1.02, effects={
        "bias_temperature": {"bias_temp_coeff_dps_per_c": 0.01},
        "scale_supply": {"scale_supply_coeff_per_v": 0.002},
        "k2_quadratic": {"k2_per_dps": 3e-6},
        "g_sensitivity_tilt": {"g_sens_dps_per_g": 0.02, "tilt_deg": 30.0, "phase_deg": 40.0},
        "warmup_drift": {"amplitude_dps": 0.1, "tau_s": 50.0},
    })
    w, dt, dv = traj.ref_rate_dps, traj.temp_c - 25, traj.supply_v - 5
    expected = (1.02 * (1 + 0.002 * dv) * w + 1.5 + 0.01 * dt + 3e-6 * w**2
                + 0.02 * math.sin(math.radians(30)) * np.cos(np.radians(traj.ref_angle_deg - 40))
                + 0.1 * np.exp(-traj.time_since_power_on_s / 50))
    assert np.allclose(m.predict(traj), expected, atol=1e-9)


def test_lag_filter_delays_a_ramp_by_tau_and_keeps_steps_settled() -> None:
    t = np.arange(0, 3, 0.01)
    ramp = np.clip((t - 1) * 100, 0, None)
    out = lag_filter(ramp, t, 0.02)
    assert abs((ramp[250] - out[250]) - 0.02 * 100) < 1e-6
    assert np.allclose(lag_filter(np.full(50, 4.0), t[:50], 0.5), 4.0)


def test_model_yaml_round_trip(tmp_path) -> None:
    m = first_order_model().with_effect("sensor_lag", {"tau_s": 0.004})
    path = save_model(m, tmp_path / "m.yaml")
    back = load_model(path)
    assert back.effects == m.effects
    assert load_model("base").effects == {}


def test_bad_model_yaml_says_what_is_wrong(tmp_path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("effects: {k4_quartic: {k4: 1.0}}\n")
    with pytest.raises(ValueError, match="unknown effect 'k4_quartic'"):
        load_model(p)
    p.write_text("effects: {k2_quadratic: {k2: 1.0}}\n")
    with pytest.raises(ValueError, match="k2_per_dps"):
        load_model(p)
    with pytest.raises(ValueError, match="neither a built-in model"):
        load_model("nonexistent_model")


def test_overlapping_allan_variance_matches_allantools() -> None:
    rng = np.random.default_rng(4)
    y = rng.normal(size=4000) + np.cumsum(rng.normal(size=4000)) * 0.01
    taus, adev, _, _ = allantools.oadev(y, rate=10.0, data_type="freq", taus=[0.1, 0.8, 6.4])
    mine = [math.sqrt(overlapping_avar(y, 0.1, m)[0]) for m in (1, 8, 64)]
    assert np.allclose(adev, mine, rtol=1e-9)
