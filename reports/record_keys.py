"""The certificate's typed accessors of `record.analysis` and `record.verification`.

What the sections hold is declared once, in procedures/runtime/results.py (each step type's
`Results` model). These helpers only turn a section into what a plot draws: finite numbers,
equal-length series, windows as pairs. A section the record lacks raises
MissingAnalysisError (the page then says so and the certificate is still issued).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from procedures.runtime.results import (
    Analysis,
    RampResults,
    StabilityResults,
    StopMethodResults,
    StopMove,
    Verification,
    VerificationRow,
)


class MissingAnalysisError(ValueError):
    """A piece of analysis the certificate wanted is not in the record; says which."""


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _numbers(values: list[float | None], what: str) -> list[float]:
    if any(v is None for v in values):
        raise MissingAnalysisError(f"{what} holds a non-number (null)")
    return [float(v) for v in values if v is not None]


def not_programmed(analysis: Analysis) -> str | None:
    """Why the fitted calibration was not written to the part (`analysis.programming`), or
    None when it was written or the record does not say."""
    programming = analysis.programming
    if programming is None or programming.programmed:
        return None
    reason = programming.reason or "no reason recorded"
    return reason.removeprefix("not programmed: ")


@dataclass(frozen=True)
class AllanSummary:
    condition: str
    tau_s: list[float]
    adev_dps: list[float]
    arw_deg_per_sqrt_h: float | None
    bias_instability_deg_per_h: float | None
    rate_random_walk_deg_per_h_per_sqrt_h: float | None


def allan(analysis: Analysis) -> AllanSummary:
    a = analysis.allan
    if a is None:
        raise MissingAnalysisError("record.analysis['allan'] is not in the record")
    tau = _numbers(a.tau_s, "analysis.allan.tau_s")
    adev = _numbers(a.adev_dps, "analysis.allan.adev_dps")
    if len(tau) != len(adev) or len(tau) < 2:
        raise MissingAnalysisError(
            f"analysis.allan: tau_s ({len(tau)}) and adev_dps ({len(adev)}) must be equal "
            "length, at least 2"
        )
    return AllanSummary(
        condition=a.condition,
        tau_s=tau,
        adev_dps=adev,
        arw_deg_per_sqrt_h=_finite(a.arw_deg_per_sqrt_h),
        bias_instability_deg_per_h=_finite(a.bias_instability_deg_per_h),
        rate_random_walk_deg_per_h_per_sqrt_h=_finite(a.rate_random_walk_deg_per_h_per_sqrt_h),
    )


@dataclass(frozen=True)
class RatePoints:
    condition: str
    rate_in_dps: list[float]
    rate_out_dps: list[float]
    residual_dps: list[float]
    scale: float | None
    bias_dps: float | None
    from_raw: bool = False  # True when computed from raw.h5 for display


def rate_table(analysis: Analysis) -> list[RatePoints]:
    """Every condition's rate-table points, sorted by condition name."""
    if not analysis.rate_table:
        raise MissingAnalysisError("record.analysis['rate_table'] is not in the record")
    out: list[RatePoints] = []
    for cond in sorted(analysis.rate_table):
        d = analysis.rate_table[cond]
        key = f"analysis.rate_table.{cond}"
        rin = _numbers(d.rate_in_dps, f"{key}.rate_in_dps")
        rout = _numbers(d.rate_out_dps, f"{key}.rate_out_dps")
        resid = _numbers(d.residual_dps, f"{key}.residual_dps")
        if len(rin) != len(rout) or (resid and len(resid) != len(rin)):
            raise MissingAnalysisError(
                f"{key}: rate_in_dps, rate_out_dps, residual_dps differ in length")
        out.append(RatePoints(cond, rin, rout, resid, _finite(d.scale), _finite(d.bias_dps)))
    return out


@dataclass(frozen=True)
class RampPoints:
    """The ramp's fitted plateaus (fixture time, the die's own sensor), each with whether the
    die was heating (`die_heating`) and, when the fit gave them, its residual; plateaus with
    a null time or temperature are left out."""

    time_s: list[float]
    die_temp_c: list[float]
    heating: list[bool]
    residual_dps: list[float | None]  # all None when the fit gave no residuals
    supply_v: list[float | None]


def die_heating(r: RampResults) -> list[bool]:
    """Per plateau: was the die heating? The sign of its own rate where the record has it
    (the die goes on heating a while after the chamber turns), else the chamber's half."""
    n = len(r.time_s)
    rates = r.die_rate_c_per_min if len(r.die_rate_c_per_min) == n else [None] * n
    halves = r.heating if len(r.heating) == n else [False] * n
    return [h if rate is None or not math.isfinite(rate) else rate > 0
            for rate, h in zip(rates, halves, strict=True)]


def ramp(analysis: Analysis) -> RampPoints:
    r = analysis.ramp
    if r is None:
        raise MissingAnalysisError(
            "record.analysis has no 'ramp' (the step ramp_calibration left no section)")
    n = len(r.time_s)
    if len(r.die_temp_c) != n or len(r.heating) != n:
        raise MissingAnalysisError(
            f"analysis.ramp: time_s ({n}), die_temp_c ({len(r.die_temp_c)}) and heating "
            f"({len(r.heating)}) differ in length")
    resid = r.residual_dps if len(r.residual_dps) == n else [None] * n
    heating = die_heating(r)
    volts = r.supply_v if len(r.supply_v) == n else [None] * n
    keep = [i for i in range(n) if _finite(r.time_s[i]) is not None
            and _finite(r.die_temp_c[i]) is not None]
    if len(keep) < 2:
        raise MissingAnalysisError(f"analysis.ramp holds {len(keep)} usable plateaus")
    return RampPoints(time_s=[float(r.time_s[i] or 0.0) for i in keep],
                      die_temp_c=[float(r.die_temp_c[i] or 0.0) for i in keep],
                      heating=[heating[i] for i in keep],
                      residual_dps=[_finite(resid[i]) for i in keep],
                      supply_v=[_finite(volts[i]) for i in keep])


@dataclass(frozen=True)
class StopSummary:
    condition: str
    bias_dps: float | None
    scale_correction: float | None
    static_windows: list[tuple[float, float]]
    integration_windows: list[tuple[float, float]]  # the moves' start and end
    moves: list[StopMove]


def _stop_summary(cond: str, d: StopMethodResults) -> StopSummary:
    return StopSummary(
        condition=cond,
        bias_dps=_finite(d.bias_dps),
        scale_correction=_finite(d.scale_correction),
        static_windows=[(w[0], w[1]) for w in d.static_windows if len(w) == 2],
        integration_windows=[(m.start_s, m.end_s) for m in d.moves
                             if m.start_s is not None and m.end_s is not None],
        moves=list(d.moves),
    )


def stop_method(analysis: Analysis) -> dict[str, StopSummary]:
    """Per condition, sorted, then the ramp's records per end (ramp_top, ramp_bottom); empty
    when the record has no stop-method analysis."""
    out = {c: _stop_summary(c, analysis.stop_method[c]) for c in sorted(analysis.stop_method)}
    ends = [] if analysis.ramp_stop is None else analysis.ramp_stop.ends
    return out | {e.label: _stop_summary(e.label, e.stop) for e in ends}


def stability(analysis: Analysis) -> dict[str, StabilityResults]:
    """The stability criterion and outcome per condition, sorted; empty when none."""
    return {c: analysis.stability[c] for c in sorted(analysis.stability)}


def verification_residuals(verification: Verification | None) -> list[VerificationRow]:
    """The verification residual rows, each with condition, rate_in_dps, error_dps."""
    return [] if verification is None else list(verification.residuals)
