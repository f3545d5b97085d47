"""Judging a measurement against its product limit (OpenHTF's validators idea).

A measurement is judged where it is set: `judge(name, value, limit)` returns the record's
`Measurement` with its outcome. Inside [low, high] but outside [marginal_low, marginal_high]
is MARGINAL: counted as a pass, flagged for the quality engineer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from procedures.config import Limit, Limits
from procedures.record import Measurement, Outcome


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
