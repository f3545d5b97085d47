"""Lot statistics from the results database: yield, failure pareto, capability (Cpk).

Definitions (stated on the lot report too):
- yield = PASS / (PASS + FAIL) over the runs selected; ERROR and ABORTED runs are station
  problems, not part outcomes, and are counted separately.
- capability uses the completed runs (PASS or FAIL) with a value; sigma is the sample
  standard deviation (n - 1) of all values in the lot, the long-term (overall) sigma, so
  strictly this is Ppk in AIAG terms. Cpk = min(USL - mean, mean - LSL) / (3 sigma); with one
  limit only, the one-sided index of that limit. Limits are those of the newest run.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from reports.lot_rows import MeasurementRow, RunRow

COMPLETED = ("PASS", "FAIL")


@dataclass(frozen=True)
class YieldSummary:
    runs: int
    passed: int
    failed: int
    errors: int
    aborted: int
    parts: int  # distinct serials

    @property
    def yield_fraction(self) -> float | None:
        done = self.passed + self.failed
        return self.passed / done if done else None


def production_runs(runs: list[RunRow], include_simulated: bool = False) -> list[RunRow]:
    """The runs a lot's numbers count: simulated runs (a bench simulator, no part) left out
    unless included, as the line's dashboard does."""
    return list(runs) if include_simulated else [r for r in runs if not r.simulated]


def yield_summary(runs: list[RunRow]) -> YieldSummary:
    counts = Counter(r.verdict for r in runs)
    return YieldSummary(
        runs=len(runs),
        passed=counts.get("PASS", 0),
        failed=counts.get("FAIL", 0),
        errors=counts.get("ERROR", 0) + counts.get("RUNNING", 0),
        aborted=counts.get("ABORTED", 0),
        parts=len({r.serial for r in runs}),
    )


def failure_pareto(rows: list[MeasurementRow]) -> list[tuple[str, int]]:
    """(measurement name, number of runs where it failed), most frequent first."""
    failing = {(m.name, m.run_id) for m in rows if m.outcome == "FAIL"}
    counts = Counter(name for name, _run in failing)
    return sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))


@dataclass(frozen=True)
class Capability:
    """One measurement's spread against its limits; `label` names it with its condition."""

    name: str
    condition: str | None
    units: str
    n: int
    mean: float | None
    sigma: float | None
    low: float | None
    high: float | None
    cpk: float | None
    limits_varied: bool
    values: tuple[float, ...]

    @property
    def too_few(self) -> bool:
        """Too few values for a capability index worth reading."""
        return self.n < MIN_CPK_N

    @property
    def label(self) -> str:
        return f"{self.name} @ {self.condition}" if self.condition else self.name


# Fewer values than this give no Cpk ("too few"): at n = 2 Bissell's interval of a Cpk of 1.33
# spans about -0.6 to 3.3 (and a Cpk of 182 was shown with -70 .. 435); at 25 it is about
# +/- 0.4, the least that still tells a capable process from an incapable one.
MIN_CPK_N = 25


def cpk(mean: float, sigma: float, low: float | None, high: float | None) -> float | None:
    """min(USL - mean, mean - LSL) / (3 sigma); one-sided with one limit; None without."""
    # A spread at rounding level (identical values) has no capability index.
    if not (math.isfinite(sigma) and sigma > 1e-12 * max(abs(mean), 1e-300)):
        return None
    sides = []
    if high is not None:
        sides.append((high - mean) / (3 * sigma))
    if low is not None:
        sides.append((mean - low) / (3 * sigma))
    return min(sides) if sides else None


def measurement_keys(rows: list[MeasurementRow]) -> list[tuple[str, str | None]]:
    """(name, condition) pairs in order of first appearance: one capability each."""
    return list(dict.fromkeys((m.name, m.condition) for m in rows))


def capability(name: str, rows: list[MeasurementRow], condition: str | None = None
               ) -> Capability:
    """Capability of one measurement (at one condition) over the completed runs in `rows`."""
    mine = [m for m in rows
            if m.name == name and m.condition == condition and m.verdict in COMPLETED]
    values = [m.value for m in mine if m.value is not None and math.isfinite(m.value)]
    newest = mine[-1] if mine else None
    low = newest.low if newest else None
    high = newest.high if newest else None
    varied = len({(m.low, m.high) for m in mine}) > 1
    n = len(values)
    mean = float(np.mean(values)) if n else None
    sigma = float(np.std(values, ddof=1)) if n >= 2 else None
    enough = n >= MIN_CPK_N and mean is not None and sigma is not None
    index = cpk(mean, sigma, low, high) if enough else None  # type: ignore[arg-type]
    return Capability(
        name=name,
        condition=condition,
        units=newest.units if newest else "",
        n=n,
        mean=mean,
        sigma=sigma,
        low=low,
        high=high,
        cpk=index,
        limits_varied=varied,
        values=tuple(values),
    )
