"""procedures.analysis.ramp_fit on synthetic ramps: a known part through a heating-and-cooling
ramp, its element lagging its sensor, with gradient bias, hysteresis and noise."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.ramp_fit import (
    RampLagTooLarge,
    RampPlateaus,
    RampSettings,
    TemperatureTrack,
    fit_ramp,
    play_state,
)

TRUTH = dict(b0=0.8, bT=0.012, bV=-0.05, s0=1.01, sT=2.5e-4, sV=-1.5e-3)
RATES = [20.0, -20.0, 50.0, -50.0, 100.0, -100.0, 200.0, -200.0]
SETTINGS = RampSettings(25.0, 5.0, hysteresis_width_c=1.0, max_tau_s=40.0, tau_bound_s=35.0)


def sensor_path(t: np.ndarray) -> np.ndarray:
    """Die sensor temperature: chamber ramp up for 420 s then down, through air and die lags."""
    sp = np.where(t < 420, 25 + t * 5 / 60, 25 + 35 - (t - 420) * 5 / 60)
    air = np.empty_like(t)
    die = np.empty_like(t)
    a = d = 25.0
    dt = t[1] - t[0]
    for i, s in enumerate(sp):
        a += (s - a) * dt / 60
        d += (a - d) * dt / 300
        air[i], die[i] = a, d
    return die


def element_path(t: np.ndarray, sensor: np.ndarray, tau: float) -> np.ndarray:
    e = np.empty_like(sensor)
    x = sensor[0]
    dt = t[1] - t[0]
    for i, s in enumerate(sensor):
        x += (s - x) * (1 - np.exp(-dt / tau))
        e[i] = x
    return e


def track() -> TemperatureTrack:
    """The sensor's temperature at 1 s, as the step keeps it."""
    t = np.arange(0.0, 1150.0, 0.1)
    return TemperatureTrack(time_s=t[::10], temp_c=sensor_path(t)[::10])


def synthetic(tau: float, seed: int = 1, noise_dps: float = 0.004,
              gradient: float = 0.004, h: float = 0.01) -> RampPlateaus:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 1150.0, 0.1)
    sensor = sensor_path(t)
    elem = element_path(t, sensor, tau)
    erate = np.gradient(elem, t)
    hyst = play_state(elem, 1.0, start=1.0)  # heated since power-on, as on the station
    rows: dict[str, list[float]] = {k: [] for k in (
        "time_s", "ref_dps", "u_ref_dps", "out_dps", "u_out_dps", "temp_c", "tdot_c_per_s",
        "supply_v")}
    srate = np.gradient(sensor, t)
    for j, t0 in enumerate(np.arange(5.0, 1140.0, 10.0)):
        i = int(np.searchsorted(t, t0 + 4.0))
        sweep = j // len(RATES)
        v = 4.75 if sweep % 2 == 0 else 5.25
        ref = RATES[j % len(RATES)]
        de, dv = elem[i] - 25.0, v - 5.0
        bias = (TRUTH["b0"] + TRUTH["bT"] * de + TRUTH["bV"] * dv
                + gradient * erate[i] * 60 + h / 2 * hyst[i])
        scale = TRUTH["s0"] * (1 + TRUTH["sT"] * de + TRUTH["sV"] * dv)
        rows["time_s"].append(t[i])
        rows["ref_dps"].append(ref)
        rows["u_ref_dps"].append(1e-4)
        rows["out_dps"].append(bias + scale * ref + rng.normal(0, noise_dps))
        rows["u_out_dps"].append(noise_dps)
        rows["temp_c"].append(sensor[i] + rng.normal(0, 0.005))
        rows["tdot_c_per_s"].append(srate[i])
        rows["supply_v"].append(v)
    return RampPlateaus.of(**rows)


NAMES = {"b0": "bias_dps", "bT": "bias_temp_coeff_dps_per_c",
         "bV": "bias_supply_coeff_dps_per_v", "s0": "scale", "sT": "scale_temp_coeff_per_c",
         "sV": "scale_supply_coeff_per_v"}


def test_play_state_switches_after_two_widths_of_reversal() -> None:
    temps = np.array([25.0, 26.0, 27.0, 30.0, 29.0, 28.0, 27.0, 26.0])
    s = play_state(temps, 1.0)
    assert s[0] == 0.0 and s[3] == 1.0
    assert s[4] == pytest.approx(0.0) and s[5] == pytest.approx(-1.0) and s[-1] == -1.0


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_the_coefficients_and_the_lag_within_u(seed: int) -> None:
    fit = fit_ramp(synthetic(tau=20.0, seed=seed), SETTINGS)
    for short, name in NAMES.items():
        got = getattr(fit.coefficients, name)
        assert abs(got - TRUTH[short]) <= fit.uncertainty_k2(name), (short, got)
    assert abs(fit.tau_s - 20.0) <= 2 * fit.u_tau_s + 1.0
    assert fit.u_tau_s < 5.0
    assert abs(fit.hysteresis_dps - 0.01) <= fit.u_hysteresis_dps + 0.003


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_with_the_track_the_temperatures_follow_the_parts_own_lag(seed: int) -> None:
    fit = fit_ramp(synthetic(tau=20.0, seed=seed), SETTINGS, track())
    for short, name in NAMES.items():
        got = getattr(fit.coefficients, name)
        assert abs(got - TRUTH[short]) <= fit.uncertainty_k2(name), (short, got)
    assert abs(fit.tau_s - 20.0) <= 2 * fit.u_tau_s + 0.5
    # carried through the lag, the first-order correction leaves (almost) nothing
    assert fit.lag_error["scale_temp_coeff_per_c"] < 0.2 * fit.u_k1["scale_temp_coeff_per_c"]
    assert fit.gradient_dps_per_c_per_min == pytest.approx(0.004 / 60 * 60, abs=0.002)


@pytest.mark.parametrize("with_track", [False, True])
def test_a_lag_far_beyond_the_typical_is_refused(with_track: bool) -> None:
    with pytest.raises(RampLagTooLarge, match="lags the temperature sensor"):
        fit_ramp(synthetic(tau=120.0), SETTINGS, track() if with_track else None)


def test_a_lag_near_the_limit_widens_u_and_stays_covered() -> None:
    narrow = fit_ramp(synthetic(tau=20.0), SETTINGS)
    wide = fit_ramp(synthetic(tau=34.0), SETTINGS)
    assert wide.tau_bound_s > narrow.tau_bound_s
    name = "scale_temp_coeff_per_c"
    assert wide.lag_error[name] > narrow.lag_error[name]
    for short, n in NAMES.items():
        assert abs(getattr(wide.coefficients, n) - TRUTH[short]) <= wide.uncertainty_k2(n)


def test_a_ramp_that_only_heats_is_refused() -> None:
    p = synthetic(tau=20.0)
    keep = p.tdot_c_per_s > 0
    half = RampPlateaus.of(**{k: getattr(p, k)[keep] for k in p.__dataclass_fields__})
    with pytest.raises(AnalysisError, match="both heat and cool"):
        fit_ramp(half, SETTINGS)
