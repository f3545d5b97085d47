"""A product's acceptance limits (`Limit`, `Limits`: the product file's `limits:`) and judging
a measurement against its limit (OpenHTF's validators idea).

A measurement is judged where it is set: `judge(name, value, limit)` returns the record's
`Measurement` with its outcome. Inside [low, high] but outside [marginal_low, marginal_high]
is MARGINAL: counted as a pass, flagged for the quality engineer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Literal

from pydantic import Field, model_validator

from common.bounded import ShortName
from procedures.runtime.record import Measurement, Outcome
from procedures.units import LimitValue, StrictModel


class Limit(StrictModel):
    """Acceptance limits of one measurement with an optional marginal band inside them.

    low <= marginal_low <= marginal_high <= high. A value inside [low, high] but outside
    [marginal_low, marginal_high] is MARGINAL: it passes but is flagged for review.
    """

    low: LimitValue | None = Field(
        None, description="lowest passing value (omit for no lower limit)"
    )
    high: LimitValue | None = Field(
        None, description="highest passing value (omit for no upper limit)"
    )
    marginal_low: LimitValue | None = Field(None, description="below this (and >= low): MARGINAL")
    marginal_high: LimitValue | None = Field(None, description="above this (and <= high): MARGINAL")
    units: ShortName = Field("", description="units of the value, for the certificate")
    on_fail: Literal["continue", "stop_part"] = Field(
        "continue",
        description="continue: a failing part goes on being measured; stop_part: it stops at "
        "once (dropped from the remaining steps, verdict FAIL, the reason names this limit)",
    )

    @model_validator(mode="after")
    def _ordered(self) -> Limit:
        chain = [
            (n, v)
            for n, v in (
                ("low", self.low),
                ("marginal_low", self.marginal_low),
                ("marginal_high", self.marginal_high),
                ("high", self.high),
            )
            if v is not None
        ]
        for (n1, v1), (n2, v2) in zip(chain, chain[1:], strict=False):
            if v1 > v2:
                raise ValueError(
                    f"{n1} ({v1}) must not exceed {n2} ({v2}); "
                    "order low <= marginal_low <= marginal_high <= high"
                )
        if self.low is None and self.high is None:
            raise ValueError("give at least one of low or high")
        return self


LIMIT_NAMES = (
    "raw_bias_dps",
    "raw_scale_error",
    "noise_arw_deg_per_sqrt_h",
    "bias_instability_deg_per_h",
    "nonlinearity_pct_fs",
    "asymmetry",
    "bias_temp_coeff_dps_per_c",
    "scale_temp_coeff_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale_supply_coeff_per_v",
    "residual_bias_dps",
    "residual_scale_error",
    "stop_table_consistency",
    "supply_current_a",
    "frames_lost_fraction",
    "turn_on_bias_repeatability_dps",
    "warm_up_time_s",
    "bias_temp_coeff2_dps_per_c2",
    "bias_temp_coeff3_dps_per_c3",
    "scale_temp_coeff2_per_c2",
    "scale_temp_coeff3_per_c3",
    "misalignment_mrad",
    "g_sensitivity_dps_per_mps2",
)


class Limits(StrictModel):
    """Limits per measurement name; a measurement without a limit is recorded, not judged."""

    raw_bias_dps: Limit | None = Field(
        None, description="uncalibrated bias at each condition, deg/s"
    )
    raw_scale_error: Limit | None = Field(
        None, description="uncalibrated scale - 1 at each condition"
    )
    noise_arw_deg_per_sqrt_h: Limit | None = Field(None, description="angle random walk")
    bias_instability_deg_per_h: Limit | None = Field(None, description="Allan floor / 0.664")
    nonlinearity_pct_fs: Limit | None = Field(
        None, description="largest residual from the line, % FS"
    )
    asymmetry: Limit | None = Field(None, description="(K+ - K-) / mean K")
    bias_temp_coeff_dps_per_c: Limit | None = Field(
        None, description="fitted bias temperature coefficient"
    )
    scale_temp_coeff_per_c: Limit | None = Field(
        None, description="fitted relative scale temperature coefficient"
    )
    bias_supply_coeff_dps_per_v: Limit | None = Field(
        None, description="fitted bias supply coefficient"
    )
    scale_supply_coeff_per_v: Limit | None = Field(
        None, description="fitted relative scale supply coefficient"
    )
    residual_bias_dps: Limit | None = Field(None, description="compensated output at rest, deg/s")
    residual_scale_error: Limit | None = Field(
        None, description="compensated scale error at the verification rates"
    )
    stop_table_consistency: Limit | None = Field(
        None, description="(stop scale - table scale) / combined k=2 uncertainty"
    )
    supply_current_a: Limit | None = Field(None, description="supply current per part, A")
    frames_lost_fraction: Limit | None = Field(None, description="lost frames / expected frames")
    turn_on_bias_repeatability_dps: Limit | None = Field(
        None, description="turn-on to turn-on bias repeatability (1 sigma), deg/s"
    )
    warm_up_time_s: Limit | None = Field(
        None, description="time from power-on until the bias settles within its band, s"
    )
    bias_temp_coeff2_dps_per_c2: Limit | None = Field(None, description="fitted b2, deg/s/C^2")
    bias_temp_coeff3_dps_per_c3: Limit | None = Field(None, description="fitted b3, deg/s/C^3")
    scale_temp_coeff2_per_c2: Limit | None = Field(None, description="fitted s2, 1/C^2")
    scale_temp_coeff3_per_c3: Limit | None = Field(None, description="fitted s3, 1/C^3")
    misalignment_mrad: Limit | None = Field(
        None, description="three-axis: off-diagonal of M over its row's diagonal, mrad"
    )
    g_sensitivity_dps_per_mps2: Limit | None = Field(
        None, description="three-axis: each element of G, deg/s per m/s^2"
    )


def outcome_of(value: float | None, limit: Limit | None, guard_band: float = 0.0) -> Outcome:
    """PASS, MARGINAL, FAIL for `value` against `limit` (no limit: PASS; no value: NOT_MEASURED).
    `guard_band` (>= 0, the expanded uncertainty under a guard-banded decision rule) narrows
    the acceptance zone to [low + guard_band, high - guard_band]."""
    if value is None:
        return Outcome.NOT_MEASURED
    if not math.isfinite(value):
        return Outcome.FAIL
    if limit is None:
        return Outcome.PASS
    if (limit.low is not None and value < limit.low + guard_band) or (
        limit.high is not None and value > limit.high - guard_band
    ):
        return Outcome.FAIL
    if (limit.marginal_low is not None and value < limit.marginal_low) or (
        limit.marginal_high is not None and value > limit.marginal_high
    ):
        return Outcome.MARGINAL
    return Outcome.PASS


def judge(
    name: str,
    value: float | None,
    limits: Limits,
    *,
    units: str = "",
    limit_name: str | None = None,
    uncertainty_k2: float | None = None,
    condition: str | None = None,
    description: str = "",
    decision_rule: str = "simple",
) -> Measurement:
    """A record measurement judged against `limits.<limit_name or name>`; under the
    "guard_banded" decision rule the limits are narrowed by `uncertainty_k2`."""
    limit: Limit | None = getattr(limits, limit_name or name, None)
    guard = 0.0
    if decision_rule == "guard_banded" and uncertainty_k2 is not None \
            and math.isfinite(uncertainty_k2):
        guard = abs(uncertainty_k2)
    return Measurement(
        name=name,
        value=None if value is None else float(value),
        units=units or (limit.units if limit else ""),
        low=limit.low if limit else None,
        high=limit.high if limit else None,
        marginal_low=limit.marginal_low if limit else None,
        marginal_high=limit.marginal_high if limit else None,
        outcome=outcome_of(value, limit, guard),
        uncertainty_k2=uncertainty_k2,
        condition=condition,
        description=description,
    )


def overall(measurements: Iterable[Measurement]) -> tuple[bool, list[str], list[str]]:
    """(all passed, names that failed, names that were marginal)."""
    failed: list[str] = []
    marginal: list[str] = []
    for m in measurements:
        label = f"{m.name}@{m.condition}" if m.condition else m.name
        if m.outcome is Outcome.FAIL:
            failed.append(label)
        elif m.outcome is Outcome.MARGINAL:
            marginal.append(label)
    return not failed, failed, marginal
