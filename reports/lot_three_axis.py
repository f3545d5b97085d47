"""The lot report's lines per axis for three-axis parts: the calibration written to them.

One line per element (b per axis, M and G per row and column, the per-axis temperature and
supply coefficients): how many completed runs, the lot's mean and spread, and the mean of
the runs' own k = 2 uncertainties, so a reader sees whether the spread is the parts' or the
measurement's. Read from the results database's calibration_elements (schema 4); a lot of
single-axis parts has none, and the report then has no such section.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence

from reportlab.lib.units import mm
from reportlab.platypus import Flowable, Paragraph

from reports.lot_rows import CalibrationElement, RunRow
from reports.styles import CELL, H2, NOTE, fmt, grid_style
from reports.table_fit import fitted_table

LABELS = {
    "bias_dps": ("b", "deg/s"),
    "matrix": ("M", "1"),
    "g_sensitivity_dps_per_mps2": ("G", "deg/s/(m/s^2)"),
    "bias_temp_coeff_dps_per_c": ("bT", "deg/s/C"),
    "bias_supply_coeff_dps_per_v": ("bV", "deg/s/V"),
    "scale_temp_coeff_per_c": ("sT", "1/C"),
    "scale_supply_coeff_per_v": ("sV", "1/V"),
}
COMPLETED = ("PASS", "FAIL")


def _p(text: object) -> Paragraph:
    return Paragraph(str(text), CELL)


def element_lines(
    elements: Sequence[CalibrationElement], runs: Sequence[RunRow]
) -> list[tuple[str, str, int, float, float | None, float | None]]:
    """(element, units, n, mean, sigma (n-1), mean U k=2) per element, over completed runs,
    in the order the elements first appear."""
    completed = {r.run_id for r in runs if r.verdict in COMPLETED}
    values: dict[tuple[str, str, str | None], list[tuple[float, float | None]]] = {}
    for e in elements:
        if e.run_id in completed and e.value is not None:
            values.setdefault((e.quantity, e.axis, e.column_axis), []).append(
                (e.value, e.uncertainty_k2))
    out = []
    for (quantity, axis, col), pairs in values.items():
        symbol, units = LABELS.get(quantity, (quantity, ""))
        name = f"{symbol}_{axis}{col or ''}"
        vs = [v for v, _ in pairs]
        us = [u for _, u in pairs if u is not None]
        sigma = statistics.stdev(vs) if len(vs) > 1 else None
        out.append((name, units, len(vs), statistics.fmean(vs), sigma,
                    statistics.fmean(us) if us else None))
    return out


def three_axis_section(
    elements: Sequence[CalibrationElement], runs: Sequence[RunRow]
) -> list[Flowable]:
    lines = element_lines(elements, runs)
    if not lines:
        return []
    rows: list[list[object]] = [[_p(h) for h in ("Element", "Units", "n", "Mean",
                                                  "Sigma (n-1)", "Mean U (k=2)")]]
    for name, units, n, mean, sigma, u in lines:
        rows.append([_p(name), _p(units), str(n), fmt(mean, 6), fmt(sigma, 3), fmt(u, 3)])
    t = fitted_table(rows, 182 * mm, grid_style(), repeatRows=1)
    return [Paragraph("Three-axis calibration written, per axis", H2), t, Paragraph(
        "Completed three-axis runs. b: bias vector; M: correction matrix (row: output axis, "
        "column: input axis); G: g-sensitivity (row: gyro axis, column: accelerometer axis); "
        "bT, bV, sT, sV: per-axis bias and scale temperature and supply coefficients. Sigma "
        "well above the mean U is the parts' own spread; near it, the measurement's.", NOTE)]
