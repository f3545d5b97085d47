"""The hysteresis state from the die readings, its correction, and the correlated error it
brings to the first-order fit (procedures/analysis/hysteresis.py, temp_supply_fit.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.hysteresis import (
    PlayOperator,
    both_sides,
    correction,
    own_correction,
    own_hysteresis,
)
from procedures.analysis.temp_supply_fit import ConditionMeasurement, fit_temp_supply


def _follow(play: PlayOperator, temps: list[float]) -> None:
    for t in temps:
        play.follow(np.full(40, t))


def test_state_is_none_before_any_reading_and_zero_at_power_on() -> None:
    play = PlayOperator(1.0)
    assert play.state is None
    play.follow([np.nan, np.nan])
    assert play.state is None
    play.follow([25.0, 25.0])
    assert play.state == 0.0


def test_heating_by_twice_the_width_saturates_and_a_small_reversal_does_not_switch() -> None:
    play = PlayOperator(1.0)
    _follow(play, list(np.linspace(25.0, 31.0, 61)))
    assert play.state == pytest.approx(1.0)
    _follow(play, [30.5])  # back by half a width: still mostly heated
    assert play.state == pytest.approx(0.5)
    _follow(play, [31.0])  # forward again inside the play: back to fully heated
    assert play.state == pytest.approx(1.0)


def test_cooling_by_twice_the_width_switches_fully_and_a_partial_reversal_is_between() -> None:
    play = PlayOperator(1.0)
    _follow(play, [25.0, 40.0])
    _follow(play, list(np.linspace(40.0, 37.0, 31)))
    assert play.state == pytest.approx(-1.0)
    play = PlayOperator(2.0)
    _follow(play, [25.0, 40.0, 39.0])  # 1 C of reversal on a 2 C width: a quarter across
    assert play.state == pytest.approx(0.5)


def test_the_block_mean_keeps_the_sensor_noise_out_of_the_state() -> None:
    rng = np.random.default_rng(3)
    play = PlayOperator(1.0)
    _follow(play, [25.0, 30.0])
    for _ in range(500):  # settled at 30 C with 0.02 C of sensor noise
        play.follow(30.0 + 0.02 * rng.standard_normal(40))
    assert play.state == pytest.approx(1.0, abs=0.01)


def test_width_must_be_positive() -> None:
    with pytest.raises(AnalysisError):
        PlayOperator(0.0)


def test_correction_carries_the_bias_to_the_midline_with_its_spread() -> None:
    heated = correction(1.0, 0.01, 0.004)
    assert heated.correction_dps == pytest.approx(-0.005)
    assert heated.u_correction_dps == pytest.approx(0.002)
    cooled = correction(-0.5, 0.01, 0.004)
    assert cooled.correction_dps == pytest.approx(0.0025)
    assert cooled.u_correction_dps == pytest.approx(0.001)
    none = correction(0.0, 0.01, 0.004)
    assert none.correction_dps == 0.0 and none.u_correction_dps == 0.0
    assert correction(1.3, 0.01, 0.004).state == 1.0  # clipped to the operator's range


def _grid(common: float) -> list[ConditionMeasurement]:
    return [
        ConditionMeasurement(t, v, 0.1 + 0.001 * (t - 25), 0.005, 1.0, 1e-5,
                             u_bias_common_dps=common)
        for t in (30.0, 50.0) for v in (4.75, 5.25)
    ]


def test_a_common_error_at_every_condition_goes_into_b0_alone() -> None:
    plain, common = fit_temp_supply(_grid(0.0)), fit_temp_supply(_grid(0.002))
    u0 = plain.uncertainty("bias_dps")
    assert common.uncertainty("bias_dps") == pytest.approx(math.hypot(u0, 0.002))
    for name in ("bias_temp_coeff_dps_per_c", "bias_supply_coeff_dps_per_v", "scale"):
        assert common.uncertainty(name) == pytest.approx(plain.uncertainty(name))
    assert common.coefficients.bias_dps == pytest.approx(plain.coefficients.bias_dps)


def test_folding_the_common_error_in_per_condition_would_understate_u_b0() -> None:
    """Why the fit carries it as correlated: four independent errors of 0.002 average down."""
    folded = [ConditionMeasurement(c.temp_c, c.supply_v, c.bias_dps,
                                   math.hypot(c.u_bias_dps, 0.002), c.scale, c.u_scale)
              for c in _grid(0.0)]
    assert (fit_temp_supply(folded).uncertainty("bias_dps")
            < fit_temp_supply(_grid(0.002)).uncertainty("bias_dps"))


def _revisit_design(h: float, noise: float = 0.0) -> tuple[list[ConditionMeasurement],
                                                            list[float]]:
    """The 2 x 2 reached by heating and a revisit 3 C below the last, cooled; biases of a
    part with b0 0.1, bT 0.001, bV 0.02 and hysteresis h."""
    rng = np.random.default_rng(7)
    points = [(30.0, 4.75, 1.0), (31.0, 5.25, 1.0), (50.5, 5.25, 1.0), (49.8, 4.75, 0.2),
              (46.8, 4.75, -1.0)]
    conds = [ConditionMeasurement(t, v, 0.1 + 0.001 * (t - 25) + 0.02 * (v - 5) + h / 2 * s
                                  + noise * rng.standard_normal(), 0.005, 1.0, 1e-5)
             for t, v, s in points]
    return conds, [s for _, _, s in points]


def test_both_sides_needs_a_state_on_each_side() -> None:
    assert not both_sides([1.0, 1.0, 1.0, 0.2])
    assert both_sides([1.0, 1.0, -0.6])
    assert not both_sides([])


def test_own_hysteresis_is_measured_and_judged_against_the_declared_spread() -> None:
    conds, states = _revisit_design(0.01)
    own = own_hysteresis(conds, states, (0.01, 0.004), (25.0, 5.0))
    assert own.hysteresis_dps == pytest.approx(0.01, abs=1e-12)
    assert 0.003 < own.u_hysteresis_dps < 0.01
    assert not own.beyond_typical
    wide = own_hysteresis(*_revisit_design(0.08), (0.01, 0.004), (25.0, 5.0))
    assert wide.hysteresis_dps == pytest.approx(0.08) and wide.beyond_typical
    with pytest.raises(AnalysisError, match="both sides"):
        own_hysteresis(conds[:4], states[:4], (0.01, 0.004), (25.0, 5.0))


def test_with_both_sides_the_fit_leaves_h_to_the_data() -> None:
    """Corrected with the own h and a free common term, b0 is the midline whatever h is,
    and its u is that of a fit with h as a fourth parameter."""
    for h in (0.01, 0.05):
        conds, states = _revisit_design(h)
        own = own_hysteresis(conds, states, (0.01, 0.004), (25.0, 5.0))
        fixed = [replace(c, bias_dps=c.bias_dps + own_correction(s, own).correction_dps,
                         u_bias_common_dps=own_correction(s, own).u_common_dps)
                 for c, s in zip(conds, states, strict=True)]
        fit = fit_temp_supply(fixed)
        assert fit.coefficients.bias_dps == pytest.approx(0.1, abs=1e-9)
        assert fit.coefficients.bias_temp_coeff_dps_per_c == pytest.approx(0.001, abs=1e-9)
        plain = fit_temp_supply(conds[:4])
        assert fit.uncertainty("bias_dps") > plain.uncertainty("bias_dps")
