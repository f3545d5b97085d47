"""procedures.analysis.ramp_linearity: nonlinearity and asymmetry from a ramp's plateaus, as
the rate table defines them at one condition, the temperature, supply, lag and hysteresis
laws taken away by the ramp's fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.ramp_fit import RampPlateaus, fit_ramp
from procedures.analysis.ramp_linearity import at_reference, ramp_linearity
from procedures.analysis.rate_table import fit_rate_table
from tests.analysis.test_ramp_fit import RATES, SETTINGS, TRUTH, synthetic, track

FULL_SCALE = 250.0


def bent(p: RampPlateaus, asymmetry: float, cubic: float) -> RampPlateaus:
    """The part's output with a scale asymmetry and a cubic bend on top of its laws."""
    r = p.ref_dps
    extra = TRUTH["s0"] * r * np.where(r > 0, asymmetry / 2, -asymmetry / 2) + cubic * r**3
    return dataclasses.replace(p, out_dps=p.out_dps + extra)


def direct(asymmetry: float, cubic: float) -> tuple[float, float]:
    """The rate table's nonlinearity and asymmetry of that bend at the reference point."""
    r = np.array(RATES)
    y = (TRUTH["b0"] + TRUTH["s0"] * r * (1 + np.where(r > 0, asymmetry, -asymmetry) / 2)
         + cubic * r**3)
    fit = fit_rate_table(r, np.full(r.size, 1e-6), y, np.full(r.size, 1e-6), FULL_SCALE)
    return fit.nonlinearity_pct_fs, fit.asymmetry_ppm * 1e-6


@pytest.mark.parametrize("seed", [1, 2])
def test_a_linear_part_shows_no_nonlinearity_nor_asymmetry(seed: int) -> None:
    p = synthetic(tau=20.0, seed=seed)
    lin = ramp_linearity(p, p.ref_dps, fit_ramp(p, SETTINGS, track()), FULL_SCALE)
    assert len(lin.input_rate_dps) == len(RATES)  # one point per commanded rate
    assert lin.nonlinearity_pct_fs <= 2 * lin.u_nonlinearity_pct_fs + 1e-3
    assert abs(lin.asymmetry_ppm) <= 2 * lin.u_asymmetry_ppm
    assert lin.u_asymmetry_ppm < 100  # the ramp's many plateaus: tighter than one pass
    assert lin.scale == pytest.approx(TRUTH["s0"], rel=1e-3)  # the line at the reference


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_bent_part_reads_as_the_rate_table_would_read_it(seed: int) -> None:
    asym, cubic = 0.002, 2e-9
    want_nl, want_asym = direct(asym, cubic)
    assert want_nl > 0.02  # a bend the test can see
    p = bent(synthetic(tau=20.0, seed=seed), asym, cubic)
    lin = ramp_linearity(p, p.ref_dps, fit_ramp(p, SETTINGS, track()), FULL_SCALE)
    # the fitted laws take a little of the bend (the rate x temperature terms see some of
    # it as the rates cycle through the ramp): within 0.01 % FS, a twentieth of the limit
    assert abs(lin.nonlinearity_pct_fs - want_nl) <= 2 * lin.u_nonlinearity_pct_fs + 0.01
    assert abs(lin.asymmetry_ppm * 1e-6 - want_asym) <= 2 * lin.u_asymmetry_ppm * 1e-6 + 5e-5


def test_at_reference_takes_the_laws_away() -> None:
    """Carried to the reference, the plateaus of one rate agree (within the noise) though
    they were measured 20 C and 0.5 V apart."""
    p = synthetic(tau=20.0, seed=4)
    y = at_reference(p, fit_ramp(p, SETTINGS, track()))
    for rate in RATES:
        sel = p.ref_dps == rate
        assert float(np.ptp(p.out_dps[sel])) > 0.05  # raw: the laws move them apart
        assert float(np.std(y[sel])) < 0.01  # noise 0.004 deg/s


def test_commanded_rates_must_match_the_plateaus() -> None:
    p = synthetic(tau=20.0, seed=1)
    with pytest.raises(AnalysisError, match="one of each per plateau"):
        ramp_linearity(p, p.ref_dps[:-1], fit_ramp(p, SETTINGS), FULL_SCALE)
