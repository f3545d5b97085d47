from __future__ import annotations

import allantools
import numpy as np
import pytest

from procedures.analysis.allan import NoiseModel, analyze_allan, overlapping_adev
from procedures.analysis.errors import AnalysisError
from tests.analysis.synth import gyro_noise, nbs14_1000

NBS14_OADEV = {1: 0.2922319, 10: 0.09159953, 100: 0.03241343}  # NIST SP 1065, table 31


def test_nbs14_1000_point_matches_nist_sp1065() -> None:
    adev = overlapping_adev(nbs14_1000(), 1.0, taus=[1, 10, 100])
    assert list(adev.tau_s) == [1.0, 10.0, 100.0]
    for tau, got in zip(adev.tau_s, adev.adev_dps, strict=True):
        want = NBS14_OADEV[int(tau)]
        assert abs(got / want - 1.0) < 1e-4, (tau, got, want)


@pytest.mark.parametrize("taus", ["octave", "log"])
def test_matches_allantools_on_a_gyro_record(taus: str) -> None:
    rng = np.random.default_rng(11)
    rate = 8.6 + gyro_noise(rng, 50_000, 100.0, arw_deg_per_sqrt_h=0.6,
                            bias_instability_deg_per_h=15.0)
    ours = overlapping_adev(rate, 100.0, taus)
    t_ref, ad_ref, _, _ = allantools.oadev(rate, rate=100.0, data_type="freq", taus=ours.tau_s)
    common = np.isin(np.round(ours.tau_s * 100), np.round(t_ref * 100))
    assert common.sum() >= 10
    ref = dict(zip(np.round(t_ref * 100).astype(int), ad_ref, strict=True))
    for m, got in zip(np.round(ours.tau_s[common] * 100).astype(int), ours.adev_dps[common],
                      strict=True):
        assert abs(got / ref[m] - 1.0) < 1e-9, (m, got, ref[m])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_one_hour_recovers_arw_and_bias_instability_within_5_percent(seed: int) -> None:
    arw, bi = 0.3, 25.0  # deg/sqrt(h), deg/h: inside the population of METHOD.md
    rng = np.random.default_rng(seed)
    rate = gyro_noise(rng, 360_000, 100.0, arw, bi)
    fit = analyze_allan(rate, 100.0).noise
    assert abs(fit.arw_deg_per_sqrt_h / arw - 1.0) < 0.05
    assert abs(fit.bias_instability_deg_per_h / bi - 1.0) < 0.05
    # each term comes from the taus where its slope holds
    assert fit.arw_region_s is not None and fit.arw_region_s[0] < 1.0
    assert fit.flat_region_s is not None and fit.flat_region_s[0] > 1.0


def test_reading_tau_1s_alone_would_be_biased_here() -> None:
    """Guard on the test above: with this much flicker the ADEV at 1 s is not N."""
    rng = np.random.default_rng(0)
    rate = gyro_noise(rng, 360_000, 100.0, 0.3, 25.0)
    adev = overlapping_adev(rate, 100.0, [1.0])
    assert adev.adev_dps[0] * 60.0 / 0.3 > 1.2


def test_rate_random_walk_recovered() -> None:
    rng = np.random.default_rng(4)
    fs, n = 50.0, 180_000
    k_true = 0.002  # deg/s/sqrt(s)
    white = 0.01 * np.sqrt(fs) * rng.standard_normal(n)
    walk = np.cumsum(rng.standard_normal(n)) * k_true / np.sqrt(fs)
    fit = analyze_allan(white + walk, fs).noise
    assert fit.rrw_region_s is not None
    assert abs(fit.model.rrw_dps_per_sqrt_s / k_true - 1.0) < 0.2
    assert abs(fit.model.arw_deg_per_sqrt_s / 0.01 - 1.0) < 0.05


def test_white_noise_reports_no_flat_part_and_an_upper_bound() -> None:
    rng = np.random.default_rng(3)
    result = analyze_allan(0.1 * rng.standard_normal(60_000), 100.0)
    assert result.noise.flat_region_s is None
    assert result.noise.bias_instability_deg_per_h == 0.0
    bound = result.bias_instability_upper_bound_deg_per_h
    assert bound == pytest.approx(result.adev.adev_dps.min() / 0.664 * 3600, rel=1e-3)


def test_noise_model_units() -> None:
    m = NoiseModel.from_datasheet(arw_deg_per_sqrt_h=0.6, bias_instability_deg_per_h=10.0)
    assert m.arw_deg_per_sqrt_s == pytest.approx(0.01)
    assert m.adev_dps(1.0) == pytest.approx(np.hypot(0.01, 0.664 * 10 / 3600), rel=1e-3)


@pytest.mark.parametrize(
    ("rate", "needle"),
    [([1.0, np.nan] * 10, "NaN"), ([1.0, 2.0, 3.0], "at least"), (np.ones((4, 4)), "1-D")],
)
def test_bad_input_is_named(rate: object, needle: str) -> None:
    with pytest.raises(AnalysisError, match=needle):
        overlapping_adev(rate, 100.0)  # type: ignore[arg-type]


def test_constant_record_fits_no_noise_without_crashing() -> None:
    result = analyze_allan(np.full(200, 3.0), 10.0)
    assert result.noise.model == NoiseModel()


def test_noise_term_uncertainties_match_their_monte_carlo_scatter() -> None:
    arw, bi = [], []
    u_arw, u_bi = [], []
    for seed in range(60):
        rng = np.random.default_rng(100 + seed)
        fit = analyze_allan(gyro_noise(rng, 30_000, 100.0, 0.3, 25.0), 100.0).noise
        arw.append(fit.arw_deg_per_sqrt_h)
        u_arw.append(fit.u_arw_deg_per_sqrt_h)
        bi.append(fit.bias_instability_deg_per_h)
        u_bi.append(fit.u_bias_instability_deg_per_h)
    # 60 records pin a standard deviation to about +/- 9 %
    assert np.std(arw, ddof=1) == pytest.approx(np.mean(u_arw), rel=0.3)
    assert np.std(bi, ddof=1) == pytest.approx(np.mean(u_bi), rel=0.3)
    assert abs(np.mean(bi) / 25.0 - 1) < 3 * np.std(bi) / np.sqrt(60)


def test_a_floor_raises_only_the_slow_terms_below_it() -> None:
    from procedures.analysis.allan import NoiseModel

    short = NoiseModel(arw_deg_per_sqrt_s=0.01, bias_instability_dps=0.0, rrw_dps_per_sqrt_s=2e-5)
    floored = short.with_floor(0.004, 1e-5)
    assert floored.arw_deg_per_sqrt_s == 0.01  # white noise is measured, never floored
    assert floored.bias_instability_dps == 0.004
    assert floored.rrw_dps_per_sqrt_s == 2e-5  # above its floor: kept
    assert float(floored.avar_dps2(8.0)) > float(short.avar_dps2(8.0))
