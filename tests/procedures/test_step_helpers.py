"""Pure helpers of the steps: stability judgement, scale source choice, read-back compare."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from drivers.protocols import CalibrationRegisters
from procedures.analysis.errors import AnalysisError
from procedures.analysis.stability import judge_stability
from procedures.runtime.run_parts import ConditionResult, StopScale
from procedures.steps.fit import scale_estimate
from procedures.steps.program import readback_differences


def _die(t: np.ndarray, tau_s: float, step_c: float = 20.0) -> np.ndarray:
    rng = np.random.default_rng(1)
    return 45.0 - step_c * np.exp(-t / tau_s) + rng.normal(0, 0.02, t.size)


def test_stability_needs_a_full_window_and_a_flat_die() -> None:
    t = np.arange(0, 3000, 0.1)
    die = _die(t, 300.0)
    early = t < 600
    v = judge_stability(t[early], die[early], 60, 0.1, 0.2)
    assert not v.stable and v.slope_c_per_min > 0.1  # still creeping at 10 min
    v = judge_stability(t, die, 60, 0.1, 0.2)
    assert v.stable and abs(v.slope_c_per_min) < 0.1 and v.band_c < 0.2
    short = t < 30
    assert not judge_stability(t[short], np.full(short.sum(), 45.0), 60, 0.1, 0.2).stable
    # a flat die at the wrong temperature fails only when a target tolerance is asked for
    flat = np.full(t.size, 40.0)
    assert judge_stability(t, flat, 60, 0.1, 0.2).stable
    assert not judge_stability(t, flat, 60, 0.1, 0.2, target_c=45.0, tolerance_c=1.0).stable


def _res(table: tuple[float, float] | None, stop: tuple[float, float] | None) -> ConditionResult:
    r = ConditionResult(name="T25_V5", temperature_c=25, supply_v=5)
    if table is not None:
        r.table_fit = SimpleNamespace(scale=table[0], u_scale=table[1])
    if stop is not None:
        r.stop = StopScale(stop[0], stop[1], bias_dps=0.0, reference_angle_deg=90.0,
                           u_reference_angle_deg=0.01)
    return r


def test_scale_source_choice_and_weighting() -> None:
    both = _res((1.0200, 1e-5), (1.0210, 3e-5))
    assert scale_estimate("rate_table", both) == (1.0200, 1e-5)
    assert scale_estimate("stop_method", both) == (1.0210, 3e-5)
    value, u = scale_estimate("both", both)
    assert value == pytest.approx((1.0200 * 9 + 1.0210) / 10)  # weights 1/u^2: 9 to 1
    assert u == pytest.approx(1 / np.sqrt(1 / 1e-10 + 1 / 9e-10))
    assert scale_estimate("both", _res(None, (1.03, 1e-4))) == (1.03, 1e-4)
    with pytest.raises(AnalysisError, match="no rate-table scale"):
        scale_estimate("rate_table", _res(None, (1.03, 1e-4)))


def test_readback_compare() -> None:
    w = CalibrationRegisters(bias_dps=0.448148629, scale=1.02378858, bias_tc_dps_per_c=0.0088)
    assert readback_differences(w, w) == []
    r = CalibrationRegisters(bias_dps=0.448148629, scale=1.0238, bias_tc_dps_per_c=0.0088)
    diffs = readback_differences(w, r)
    assert len(diffs) == 1 and diffs[0].startswith("scale")
