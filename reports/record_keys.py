"""What the reports read from `record.analysis` and `record.verification`, and how.

The engine owns `RunRecord.analysis` (a free dict); the certificate reads the keys below.
Every key is optional: a plot or table whose data is absent says so on the page and the
certificate is still issued. Arrays are plain JSON lists of numbers; times are on the
fixture clock (the same clock as `raw.h5` `/samples/time_s` and `/segments`).

    analysis["stop_method"][<condition>] = {
        "bias_dps": float, "bias_correction_dps": float, "scale_correction": float,
        "static_windows": [[start_s, end_s], ...],        # where the bias was averaged
        "moves": [{"start_s", "end_s", "measured_angle_deg", "scale_correction"}, ...],
    }   # "moves" start/end are the integration windows; same keys as `station analyze
        # stop-method --json`. Windows missing here are taken from raw.h5 /segments rows
        # of kind stop_static (static) and stop_move (integration).
    analysis["rate_table"][<condition>] = {
        "rate_in_dps": [...], "rate_out_dps": [...],      # one point per plateau
        "residual_dps": [...],                            # output minus the fitted line
        "scale": float, "bias_dps": float,                # the fitted line
    }   # missing: the plateau means are computed from raw.h5 (segments of kind plateau)
        # for display only, and the page says so.
    analysis["allan"] = {
        "condition": str, "tau_s": [...], "adev_dps": [...],
        "arw_deg_per_sqrt_h": float, "bias_instability_deg_per_h": float,
        "rate_random_walk_deg_per_h_per_sqrt_h": float,   # optional
    }
    analysis["stability"][<condition>] = {
        "window_s": float,                                # judged over the last window_s
        "band_c": float,                                  # largest peak-to-peak in the window
        "max_rate_c_per_min": float,                      # largest |slope| in the window
        "tolerance_c": float | None,                      # optional: within this of setpoint
        "time_to_stability_s": float, "stable": bool,
    }   # any subset; the die temperature curve itself comes from raw.h5 /samples within
        # the segment of kind stabilise of that condition (set -> declared stable).
    verification = {                                      # RunRecord.verification
        "residuals": [{"condition": str, "rate_in_dps": float, "error_dps": float,
                       "error_pct": float (optional)}, ...],
        "max_error_pct": float (optional), "passed": bool (optional),
    }
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

STOP_METHOD = "stop_method"
RATE_TABLE = "rate_table"
ALLAN = "allan"
STABILITY = "stability"


class MissingAnalysisError(ValueError):
    """A piece of analysis the certificate wanted is not in the record; says which key."""


def _finite_list(value: Any, key: str) -> list[float]:
    if not isinstance(value, list | tuple):
        raise MissingAnalysisError(f"{key} is not a list of numbers")
    out: list[float] = []
    for v in value:
        try:
            f = float(v)
        except (TypeError, ValueError) as exc:
            raise MissingAnalysisError(f"{key} holds a non-number ({v!r})") from exc
        out.append(f)
    return out


def _opt_float(d: dict[str, Any], key: str) -> float | None:
    v = d.get(key)
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def not_programmed(analysis: dict[str, Any]) -> str | None:
    """Why the fitted calibration was not written to the part (the program step's
    `analysis.programming`), or None when it was written or the record does not say."""
    programming = analysis.get("programming")
    if not isinstance(programming, dict) or programming.get("programmed") is not False:
        return None
    reason = str(programming.get("reason") or "no reason recorded")
    return reason.removeprefix("not programmed: ")


def section(analysis: dict[str, Any], key: str) -> dict[str, Any]:
    """`analysis[key]` as a dict, or MissingAnalysisError naming the key."""
    value = analysis.get(key)
    if not isinstance(value, dict) or not value:
        raise MissingAnalysisError(f"record.analysis[{key!r}] is not in the record")
    return value


@dataclass(frozen=True)
class AllanSummary:
    condition: str
    tau_s: list[float]
    adev_dps: list[float]
    arw_deg_per_sqrt_h: float | None
    bias_instability_deg_per_h: float | None
    rate_random_walk_deg_per_h_per_sqrt_h: float | None


def allan(analysis: dict[str, Any]) -> AllanSummary:
    a = section(analysis, ALLAN)
    tau = _finite_list(a.get("tau_s"), "analysis.allan.tau_s")
    adev = _finite_list(a.get("adev_dps"), "analysis.allan.adev_dps")
    if len(tau) != len(adev) or len(tau) < 2:
        raise MissingAnalysisError(
            f"analysis.allan: tau_s ({len(tau)}) and adev_dps ({len(adev)}) must be equal "
            "length, at least 2"
        )
    return AllanSummary(
        condition=str(a.get("condition", "")),
        tau_s=tau,
        adev_dps=adev,
        arw_deg_per_sqrt_h=_opt_float(a, "arw_deg_per_sqrt_h"),
        bias_instability_deg_per_h=_opt_float(a, "bias_instability_deg_per_h"),
        rate_random_walk_deg_per_h_per_sqrt_h=_opt_float(
            a, "rate_random_walk_deg_per_h_per_sqrt_h"
        ),
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


def rate_table(analysis: dict[str, Any]) -> list[RatePoints]:
    """Every condition's rate-table points, sorted by condition name."""
    sec = section(analysis, RATE_TABLE)
    out: list[RatePoints] = []
    for cond in sorted(sec):
        d = sec[cond]
        if not isinstance(d, dict):
            continue
        key = f"analysis.rate_table.{cond}"
        rin = _finite_list(d.get("rate_in_dps"), f"{key}.rate_in_dps")
        rout = _finite_list(d.get("rate_out_dps"), f"{key}.rate_out_dps")
        res = d.get("residual_dps")
        resid = _finite_list(res, f"{key}.residual_dps") if res is not None else []
        if len(rin) != len(rout) or (resid and len(resid) != len(rin)):
            raise MissingAnalysisError(
                f"{key}: rate_in_dps, rate_out_dps, residual_dps differ in length")
        out.append(
            RatePoints(cond, rin, rout, resid, _opt_float(d, "scale"), _opt_float(d, "bias_dps"))
        )
    if not out:
        raise MissingAnalysisError("record.analysis['rate_table'] holds no condition")
    return out


@dataclass(frozen=True)
class StopSummary:
    condition: str
    bias_dps: float | None
    scale_correction: float | None
    static_windows: list[tuple[float, float]]
    integration_windows: list[tuple[float, float]]
    moves: list[dict[str, Any]]


def _windows(value: Any) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    if isinstance(value, list):
        for w in value:
            if isinstance(w, list | tuple) and len(w) == 2:
                try:
                    out.append((float(w[0]), float(w[1])))
                except (TypeError, ValueError):
                    continue
    return out


def stop_method(analysis: dict[str, Any]) -> dict[str, StopSummary]:
    """Per condition; empty dict when the record has no stop-method analysis."""
    sec = analysis.get(STOP_METHOD)
    if not isinstance(sec, dict):
        return {}
    out: dict[str, StopSummary] = {}
    for cond in sorted(sec):
        d = sec[cond]
        if not isinstance(d, dict):
            continue
        moves = [m for m in d.get("moves", []) or [] if isinstance(m, dict)]
        integ = []
        for m in moves:
            s, e = _opt_float(m, "start_s"), _opt_float(m, "end_s")
            if s is not None and e is not None:
                integ.append((s, e))
        out[cond] = StopSummary(
            condition=cond,
            bias_dps=_opt_float(d, "bias_dps"),
            scale_correction=_opt_float(d, "scale_correction"),
            static_windows=_windows(d.get("static_windows")),
            integration_windows=integ,
            moves=moves,
        )
    return out


@dataclass(frozen=True)
class StabilityCriterion:
    condition: str
    band_c: float | None
    tolerance_c: float | None
    window_s: float | None
    max_rate_c_per_min: float | None
    time_to_stability_s: float | None
    stable: bool | None


def stability(analysis: dict[str, Any]) -> dict[str, StabilityCriterion]:
    sec = analysis.get(STABILITY)
    if not isinstance(sec, dict):
        return {}
    out: dict[str, StabilityCriterion] = {}
    for cond in sorted(sec):
        d = sec[cond]
        if not isinstance(d, dict):
            continue
        stable = d.get("stable")
        out[cond] = StabilityCriterion(
            condition=cond,
            band_c=_opt_float(d, "band_c"),
            tolerance_c=_opt_float(d, "tolerance_c"),
            window_s=_opt_float(d, "window_s"),
            max_rate_c_per_min=_opt_float(d, "max_rate_c_per_min"),
            time_to_stability_s=_opt_float(d, "time_to_stability_s"),
            stable=stable if isinstance(stable, bool) else None,
        )
    return out


def verification_residuals(verification: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The verification residual rows, each with condition, rate_in_dps, error_dps."""
    if not isinstance(verification, dict):
        return []
    rows = verification.get("residuals")
    if not isinstance(rows, list):
        return []
    return [r for r in rows if isinstance(r, dict)]
