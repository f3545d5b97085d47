"""The world's part: error model, effects, noise terms, thermal and power behaviour."""

import allantools
import numpy as np
import pytest

from drivers.protocols import CalibrationRegisters
from drivers.sim.config import PartPhysicsConfig, PartSpec
from drivers.sim.gyro import GM_TAUS_S, PartModel, gauss_markov_avar
from drivers.sim.population import resolve_part

QUIET = {
    "arw_deg_per_sqrt_h": 0.0,
    "bias_instability_deg_per_h": 0.0,
    "rrw_deg_per_h_per_sqrt_h": 0.0,
}
COEFFS = {
    "bias_dps": 8.6,
    "scale": 1.0567,
    "bias_temp_coeff_dps_per_c": 0.01,
    "scale_temp_coeff_per_c": 2e-4,
    "bias_supply_coeff_dps_per_v": 0.05,
    "scale_supply_coeff_per_v": 1e-3,
}


def _part(effects: dict | None = None, **extra: float) -> PartModel:
    spec = PartSpec(
        socket=1, serial="SIM-UNIT", **{**QUIET, **COEFFS, **extra}, effects=effects or {}
    )
    part = PartModel(resolve_part(spec), PartPhysicsConfig(), seed=0, t_s=0.0, air_c=35.0)
    return part


def _out(
    part: PartModel,
    w: np.ndarray,
    angle: np.ndarray | None = None,
    v: float = 5.25,
    t: np.ndarray | None = None,
) -> np.ndarray:
    t = np.linspace(0.0, 1.0, w.size) if t is None else t
    angle = np.zeros_like(w) if angle is None else angle
    y, _ = part.raw_output_dps(t, w, angle, v, 0.005)
    return y


def test_first_order_model_matches_design_formula() -> None:
    part = _part()
    w = np.array([-200.0, -10.0, 0.0, 50.0, 250.0])
    d_t, d_v = 35.0 - 25.0, 0.25
    expected = 1.0567 * (1 + 2e-4 * d_t + 1e-3 * d_v) * w + 8.6 + 0.01 * d_t + 0.05 * d_v
    assert _out(part, w) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(
    ("effect", "params", "w", "extra"),
    [
        ("k2_quadratic", {"k2_per_dps": 5e-6}, 200.0, 5e-6 * 200.0**2),
        ("k3_cubic", {"k3_per_dps2": 2e-9}, -150.0, 2e-9 * (-150.0) ** 3),
    ],
)
def test_polynomial_effects_add_their_term(
    effect: str, params: dict, w: float, extra: float
) -> None:
    base = _out(_part(), np.array([w]))
    with_effect = _out(_part({effect: params}), np.array([w]))
    assert with_effect[0] - base[0] == pytest.approx(extra, rel=1e-9)


def test_scale_asymmetry_changes_positive_and_negative_scale_differently() -> None:
    part = _part({"scale_asymmetry": {"asymmetry": 0.01}}, bias_dps=0.0)
    plain = _part(bias_dps=0.0)
    w = np.array([100.0, -100.0])
    scale = 1.0567 * (1 + 2e-4 * 10.0 + 1e-3 * 0.25)
    # K+ = scale (1 + 0.005), K- = scale (1 - 0.005): both shift the output up by 0.5 scale
    assert _out(part, w) - _out(plain, w) == pytest.approx([0.5 * scale, 0.5 * scale], rel=1e-9)


def test_g_sensitivity_follows_table_angle() -> None:
    part = _part(
        {"g_sensitivity_tilt": {"g_sens_dps_per_g": 0.012, "tilt_deg": 30.0, "phase_deg": 90.0}}
    )
    plain = _part()
    angles = np.array([0.0, 90.0, 180.0, 270.0])
    w = np.zeros(4)
    diff = _out(part, w, angles) - _out(plain, w, angles)
    assert diff == pytest.approx([0.0, 0.006, 0.0, -0.006], abs=1e-12)


def test_sensor_lag_is_a_first_order_step_response() -> None:
    part = _part({"sensor_lag": {"tau_s": 0.1}}, bias_dps=0.0, scale=1.0)
    t = np.arange(1, 401) * 0.005
    y, _ = part.raw_output_dps(np.zeros(1), np.zeros(1), np.zeros(1), 5.0, 0.005)
    w = np.full(t.size, 100.0)
    y, _ = part.raw_output_dps(t, w, np.zeros_like(w), 5.0, 0.005)
    d_t = 35.0 - 25.0
    final = 1.0 * (1 + 2e-4 * d_t) * 100 + 0.01 * d_t
    # after one time constant (20 samples at 5 ms) the step is 63 % done
    assert (y[19] - y[0] * 0) / final == pytest.approx(1 - np.exp(-0.1 / 0.1), abs=0.03)
    assert y[-1] == pytest.approx(final, rel=1e-6)


def test_sensor_lag_delays_a_ramp_by_tau_even_below_the_output_period() -> None:
    # 5 ms lag at a 10 ms output period: a discrete one-pole filter y = a y + (1 - a) x would
    # delay a ramp by only dt a / (1 - a) = 1.6 ms; the part must behave as the continuous lag
    tau, dt, accel = 0.005, 0.01, 200.0
    part = _part({"sensor_lag": {"tau_s": tau}}, bias_dps=0.0, scale=1.0,
                 scale_temp_coeff_per_c=0.0, bias_temp_coeff_dps_per_c=0.0)
    plain = _part(bias_dps=0.0, scale=1.0, scale_temp_coeff_per_c=0.0,
                  bias_temp_coeff_dps_per_c=0.0)
    t = np.arange(1, 101) * dt
    w = np.minimum(accel * t, 100.0)  # ramp for 0.5 s, then a plateau
    lagged, _ = part.raw_output_dps(t, w, np.zeros_like(w), 5.0, dt)
    ideal, _ = plain.raw_output_dps(t, w, np.zeros_like(w), 5.0, dt)
    on_ramp = (t > 0.1) & (t < 0.45)
    assert np.allclose(ideal[on_ramp] - lagged[on_ramp], accel * tau, rtol=1e-3)
    assert lagged[-1] == pytest.approx(ideal[-1], abs=1e-9)  # settled on the plateau
    # a pause in sampling: the lag restarts settled, with no memory of the old input
    later, _ = part.raw_output_dps(t + 10.0, np.full(t.size, -50.0), np.zeros_like(w), 5.0, dt)
    assert later[0] == pytest.approx(-50.0 + ideal[-1] - 100.0, abs=1e-9)


def test_warmup_drift_decays_from_power_on() -> None:
    part = _part({"warmup_drift": {"amplitude_dps": 0.5, "tau_s": 60.0}})
    plain = _part()
    for p in (part, plain):
        p.step(10.0, 10.0, 35.0, 5.0)
    t = np.array([10.0, 70.0])
    w = np.zeros(2)
    diff = _out(part, w, t=t, v=5.0) - _out(plain, w, t=t, v=5.0)
    assert diff == pytest.approx([0.5, 0.5 * np.exp(-1)], rel=1e-6)


def test_compensation_with_true_registers_recovers_the_rate() -> None:
    part = _part()
    part.cal = CalibrationRegisters(
        bias_dps=8.6,
        scale=1.0567,
        bias_tc_dps_per_c=0.01,
        scale_tc_per_c=2e-4,
        bias_vc_dps_per_v=0.05,
        scale_vc_per_v=1e-3,
    )
    w = np.linspace(-250, 250, 11)
    raw, die = part.raw_output_dps(np.zeros(11), w, np.zeros(11), 5.25, 0.005)
    assert part.compensate(raw, die, 5.25) == pytest.approx(w, abs=1e-9)


def test_white_noise_gives_the_angle_random_walk() -> None:
    part = _part(arw_deg_per_sqrt_h=0.6)
    n, dt = 200_000, 0.01
    t = np.arange(n) * dt
    y, _ = part.raw_output_dps(t, np.zeros(n), np.zeros(n), 5.0, dt)
    taus, adev, _, _ = allantools.oadev(y - y.mean(), rate=1 / dt, data_type="freq", taus=[1.0])[:4]
    assert adev[0] == pytest.approx(0.6 / 60.0, rel=0.08)  # N in deg/sqrt(s) at tau = 1 s


def test_bias_instability_flat_part_is_0664_b() -> None:
    b_dph = 15.0
    # analytic: the summed Gauss-Markov Allan deviation peaks at 0.664 B
    part = _part(bias_instability_deg_per_h=b_dph)
    tau = np.logspace(-1, 4, 400)
    avar = sum(gauss_markov_avar(tau, c, part._gm_sigma) for c in GM_TAUS_S)
    assert np.sqrt(avar.max()) == pytest.approx(0.664 * b_dph / 3600, rel=1e-6)
    # and the generated noise shows it
    n, dt = 200_000, 0.1
    y, _ = part.raw_output_dps(np.arange(n) * dt, np.zeros(n), np.zeros(n), 5.0, dt)
    taus, adev, _, _ = allantools.oadev(
        y, rate=1 / dt, data_type="freq", taus=np.logspace(0.5, 3, 12)
    )[:4]
    assert adev.max() == pytest.approx(0.664 * b_dph / 3600, rel=0.3)
    # it is flat within a factor of two across two decades
    assert adev.max() / adev.min() < 2.0


def test_die_lags_the_air_and_self_heats_more_at_higher_supply() -> None:
    phys = PartPhysicsConfig(die_tau_s=300.0, self_heat_c_per_w=40.0, self_heat_tau_s=90.0)
    spec = PartSpec(socket=1, serial="SIM-HEAT", supply_current_a=0.025)
    parts = {v: PartModel(resolve_part(spec), phys, 0, 0.0, 25.0) for v in (4.75, 5.25)}
    for v, part in parts.items():
        for k in range(1, 601):
            part.step(float(k), 1.0, 45.0, v)
    hot, cool = parts[5.25], parts[4.75]
    # after 600 s = 2 tau the unheated die is 86 % of the way to the air
    assert cool.die_c == pytest.approx(25 + 20 * (1 - np.exp(-2)), abs=0.05)
    # self-heating: 40 C/W * V^2 * 5 mS, settled after 600 s
    assert hot.heat_c == pytest.approx(40 * 5.25**2 * 0.005, rel=0.01)
    assert hot.die_temp_c() > cool.die_temp_c()
    assert cool.powered and cool.power_on_s == 1.0
    cool.step(601.0, 1.0, 45.0, 3.0)  # brown-out
    assert not cool.powered and cool.power_on_s is None
