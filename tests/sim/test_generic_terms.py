"""The bench carries the generic terms of an extended model (lib_... ids) on a part's output."""

import numpy as np
import pytest

from drivers.sim.config import PartPhysicsConfig, PartSpec, SimConfigError, parse_sim_config
from drivers.sim.gyro import PartModel
from drivers.sim.population import resolve_part

QUIET = {
    "arw_deg_per_sqrt_h": 0.0,
    "bias_instability_deg_per_h": 0.0,
    "rrw_deg_per_h_per_sqrt_h": 0.0,
    "bias_dps": 1.5,
    "scale": 1.02,
    "bias_temp_coeff_dps_per_c": 0.0,
    "scale_temp_coeff_per_c": 0.0,
    "bias_supply_coeff_dps_per_v": 0.0,
    "scale_supply_coeff_per_v": 0.0,
}


def _part(effects: dict, air_c: float = 35.0) -> PartModel:
    spec = PartSpec(socket=1, serial="SIM-GEN", **QUIET, effects=effects)
    return PartModel(resolve_part(spec), PartPhysicsConfig(), seed=0, t_s=0.0, air_c=air_c)


def _extra(effects: dict, w: np.ndarray, angle: np.ndarray, v: float = 5.25) -> np.ndarray:
    """Output with the terms minus the same part's output without them."""
    t = np.linspace(0.0, 1.0, w.size)
    with_terms, _ = _part(effects).raw_output_dps(t, w, angle, v, 0.005)
    without, _ = _part({}).raw_output_dps(t, w, angle, v, 0.005)
    return with_terms - without


def _extra_now(part: PartModel, quiet: PartModel) -> float:
    """The terms' output at rest at each part's latest time: with them minus without."""
    t, still = np.array([part._hist_t[1]]), np.zeros(1)
    y, _ = part.raw_output_dps(t, still, still, 5.0, 0.05)
    y0, _ = quiet.raw_output_dps(np.array([quiet._hist_t[1]]), still, still, 5.0, 0.05)
    return float((y - y0)[0])


def test_product_term_of_rate_temperature_supply() -> None:
    w = np.array([-100.0, 0.0, 50.0, 200.0])
    extra = _extra({"lib_w_dT_dV": {"coeff": 2e-4}}, w, np.zeros_like(w))
    assert extra == pytest.approx(2e-4 * w * (35.0 - 25.0) * 0.25, abs=1e-12)


def test_powers_and_sign_terms() -> None:
    w = np.array([-100.0, -1.0, 3.0, 200.0])
    extra = _extra({"lib_dT2": {"coeff": 1e-3}, "lib_sgnw": {"coeff": 0.02}}, w, np.zeros(4))
    assert extra == pytest.approx(1e-3 * 10.0**2 + 0.02 * np.sign(w), abs=1e-12)


def test_angle_harmonic_is_twice_the_table_angle() -> None:
    angle = np.array([0.0, 45.0, 90.0, 180.0, 270.0])
    extra = _extra({"lib_angleh2": {"amplitude_dps": 0.03, "phase_deg": 40.0}}, np.zeros(5), angle)
    assert extra == pytest.approx(0.03 * np.cos(np.radians(2 * angle - 40.0)), abs=1e-12)
    # not once per turn: 0 and 180 deg give the same bias
    assert extra[0] == pytest.approx(extra[3])


def test_temperature_rate_term_follows_the_die() -> None:
    part = _part({"lib_dTdt": {"coeff": 0.9}}, air_c=25.0)
    quiet = _part({}, air_c=25.0)
    for p in (part, quiet):  # chamber air at 45 C: the die warms at a known rate
        p.step(10.0, 10.0, 45.0, 5.0)
    d0 = part._hist_die[0]
    d1 = part._hist_die[1]
    t = np.linspace(9.0, 10.0, 20)
    y, _ = part.raw_output_dps(t, np.zeros(20), np.zeros(20), 5.0, 0.05)
    y0, _ = quiet.raw_output_dps(t, np.zeros(20), np.zeros(20), 5.0, 0.05)
    assert d1 > d0
    assert y - y0 == pytest.approx(np.full(20, 0.9 * (d1 - d0) / 10.0), rel=1e-9)


def test_temperature_direction_term_is_plus_after_heating_and_minus_after_cooling() -> None:
    """lib_dTdir (the discrepancy vocabulary's temperature_direction): +coeff once the die has
    risen 2 C (a play operator of half-width 1 C), -coeff once it has fallen 2 C."""
    part = _part({"lib_dTdir": {"coeff": 0.01}}, air_c=25.0)
    quiet = _part({}, air_c=25.0)

    def extra() -> float:
        return _extra_now(part, quiet)

    assert extra() == pytest.approx(0.0, abs=1e-12)  # no history yet
    for k in range(1, 400):  # chamber at 45 C: heated
        for p in (part, quiet):
            p.step(float(k), 1.0, 45.0, 5.0)
    assert extra() == pytest.approx(0.01, rel=1e-9)
    for k in range(400, 800):  # back to 25 C: cooled
        for p in (part, quiet):
            p.step(float(k), 1.0, 25.0, 5.0)
    assert extra() == pytest.approx(-0.01, rel=1e-9)


def test_parts_without_generic_terms_are_unchanged() -> None:
    w = np.array([-50.0, 0.0, 50.0])
    assert not _part({})._generic
    assert _extra({}, w, np.zeros(3)) == pytest.approx(np.zeros(3), abs=0)


@pytest.mark.parametrize(
    ("effects", "message"),
    [
        ({"lib_w_q": {"coeff": 1.0}}, "unknown factor 'q'"),
        ({"lib_w2_dT2": {"coeff": 1.0}}, "at most third order"),
        ({"lib_angleh2": {"coeff": 1.0}}, "amplitude_dps"),
        ({"lib_dT2": {"amplitude_dps": 1.0, "phase_deg": 0.0}}, "coeff"),
        ({"lib_angleh7": {"amplitude_dps": 1.0, "phase_deg": 0.0}}, "harmonics 1 to 4"),
        ({"lib_w_exp0s": {"coeff": 1.0}}, "1 to 100000 s"),
    ],
)
def test_bad_generic_terms_are_refused_with_what_is_allowed(effects: dict, message: str) -> None:
    with pytest.raises(SimConfigError, match=message):
        parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-1", "effects": effects}]})


def test_a_model_yaml_effects_map_is_a_valid_part_entry() -> None:
    effects = {
        "k2_quadratic": {"k2_per_dps": 2e-6},
        "lib_dTdt": {"coeff": 0.5},
        "lib_angleh2": {"amplitude_dps": 0.02, "phase_deg": -30.0},
    }
    cfg = parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-1", "effects": effects}]})
    assert cfg.parts[0].effects == effects


def test_lagged_temperature_rate_term_is_the_rate_of_a_temperature_following_the_die() -> None:
    """lib_dTdtlag20s (the discrepancy library's element-lagged rate): (die - T_lag) / 20 s,
    T_lag following the die first order over 20 s from the die's temperature at power-on;
    0 at power-on, towards the die's own rate when the die moves steadily."""
    part = _part({"lib_dTdtlag20s": {"coeff": 1.0}}, air_c=25.0)
    quiet = _part({}, air_c=25.0)

    def extra() -> float:
        return _extra_now(part, quiet)

    lagged = part.die_temp_c()  # where it starts: the die's temperature at power-on
    for p in (part, quiet):
        p.step(0.5, 0.5, 25.0, 5.0)  # powered on at 25 C air: the die self-heats
    lagged += (part._hist_die[1] - lagged) * (1.0 - np.exp(-0.5 / 20.0))
    assert extra() == pytest.approx((part._hist_die[1] - lagged) / 20.0, rel=1e-9)
    assert abs(extra()) < 0.01  # a 0.5 s old element has hardly fallen behind
    a = np.exp(-1.0 / 20.0)
    for k in range(1, 300):  # the chamber at 45 C: the die warms
        for p in (part, quiet):
            p.step(0.5 + k, 1.0, 45.0, 5.0)
        lagged += (part._hist_die[1] - lagged) * (1.0 - a)
    rate = part._hist_die[1] - part._hist_die[0]
    assert extra() == pytest.approx((part._hist_die[1] - lagged) / 20.0, rel=1e-9)
    assert extra() > 0.0 and extra() == pytest.approx(rate, rel=0.3)
