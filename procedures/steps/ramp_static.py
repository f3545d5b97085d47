"""The ramp step's static dwell: the table at rest for `static_s` while the dies come to rest
after the turn at the bottom (near the span's bottom, every die slower than
`static_below_c_per_min`: the dwell takes the place of plateaus the table would have cycled
through until they are at rest, and costs the ramp little). The part's noise
from its Allan deviation (procedures/analysis/allan.py), recorded as the `bias` step records
it at eol-rate-table's first condition: analysis.allan, noise_arw_deg_per_sqrt_h and
bias_instability_deg_per_h.

The die still moves a little meanwhile, and its bias with it; the part of the output that
follows the die's own sensor linearly is taken out before the Allan deviation (a temperature
drift is no noise of the part's)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from procedures.analysis.allan import AllanAnalysis, NoiseModel, analyze_allan, fit_noise_model
from procedures.analysis.errors import AnalysisError
from procedures.runtime.record import Verdict
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.bias import record_allan

MIN_TEMP_SPAN_C = 0.05  # below this the die did not move enough to tell a drift


def static_dwell(ctx: RunContext, static_s: float, accel_dps2: float,
                 timeout_s: float) -> tuple[float, float]:
    """The table to rest, then `static_s` of static record; its (t0, t1) station times."""
    table = ctx.instruments.need_table()
    table.set_rate(0.0, accel_dps2)
    table.wait_at_rate(timeout_s)
    ctx.instruments.snapshot()
    t0 = ctx.wait.clock.now_s()
    ctx.wait.sleep(static_s)
    t1 = ctx.wait.clock.now_s()
    ctx.instruments.snapshot()
    return t0, t1


def without_temperature(rate_dps: NDArray[Any], temp_c: NDArray[Any]) -> NDArray[np.float64]:
    """The output less its linear dependence on the die's sensor (least squares), when the
    die moved; else the output as it is."""
    y = np.asarray(rate_dps, dtype=np.float64)
    t = np.asarray(temp_c, dtype=np.float64)
    if t.size < 3 or float(np.ptp(t)) < MIN_TEMP_SPAN_C:
        return y
    slope = np.polyfit(t - t.mean(), y, 1)[0]
    return np.asarray(y - slope * (t - t.mean()), dtype=np.float64)


def record_static_noise(ctx: RunContext, part: PartRun, t0: float, t1: float,
                        condition: str) -> AllanAnalysis | None:
    """One part's static record: its Allan deviation, analysis.allan and the noise
    measurements; a record the analysis cannot use leaves the part ERROR. Returns the
    record's Allan analysis (None: not measured)."""
    data = samples_between(ctx, part, t0, t1)
    if not check_window(ctx, part, data, "ramp static dwell", t1 - t0):
        return None
    try:
        allan = analyze_allan(without_temperature(data["rate_dps"], data["temp_c"]),
                              sample_rate_hz(ctx))
    except AnalysisError as exc:
        ctx.parts.drop(part, Verdict.ERROR, f"ramp static dwell: {exc}")
        return None
    t = data["time_s"]
    ctx.records.segment(part, "static", 0, float(t[0]), float(t[-1]), ref_rate_dps=0.0)
    record_allan(ctx, part, allan, float(t[-1] - t[0]), condition)
    return allan


def wander_model(allan: AllanAnalysis) -> NoiseModel:
    """The dwell's noise terms as an uncertainty needs them: fitted with none dropped.

    The reported model drops a term less than 3 sigma above zero (a bias instability a
    minute cannot resolve reads 0, and the stop method then takes the product's typical
    value), which biases it low exactly for the parts whose bias wanders most: on the
    simulated bench a part drawn at 24 deg/h (typical 15) had its stop scale's u some 20 %
    short. Kept, a marginal term is an unbiased estimate of the wander, what a k=1
    uncertainty needs (tests/procedures/test_ramp_stop_wander.py)."""
    return fit_noise_model(allan.adev, min_significance=0.0).model
