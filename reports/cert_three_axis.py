"""The certificate's section for a three-axis part: the vectors and matrices written to it.

b (3), M (3 x 3: scale on the diagonal, misalignment off it, also in mrad), G (3 x 3) and the
per-axis temperature and supply coefficients, each value with its expanded (k = 2)
uncertainty; the limits judged on them (their rows in the Results table); and the
programming and read-back check. A single-axis record has no such block, and this section
then adds nothing (its certificate is unchanged).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, KeepTogether, Paragraph, Table

from procedures.runtime.record import (
    ArrayValue,
    CalibrationThreeAxis,
    Outcome,
    RunRecord,
    three_axis_block,
)
from reports.cert_inputs import CertificateInputs
from reports.styles import BODY, CELL, H2, NOTE, fmt, grid_style
from reports.table_fit import fitted_table

WIDTH = 182 * mm

AXES = "xyz"
PER_AXIS = (
    ("bias_temp_coeff_dps_per_c", "Bias temp. coeff.", "deg/s/C"),
    ("bias_supply_coeff_dps_per_v", "Bias supply coeff.", "deg/s/V"),
    ("scale_temp_coeff_per_c", "Scale temp. coeff.", "1/C"),
    ("scale_supply_coeff_per_v", "Scale supply coeff.", "1/V"),
)
# the fit's per-axis measurement names start with these (procedures/steps/three_axis_fit.py)
JUDGED_PREFIXES = ("raw_bias_", "raw_scale_error_", "misalignment_", "g_sensitivity_",
                   "bias_temp_coeff_", "bias_supply_coeff_", "scale_temp_coeff_",
                   "scale_supply_coeff_")


def _p(text: object) -> Paragraph:
    return Paragraph(str(text), CELL)


def _pm(value: Any, u: Any, digits: int = 6) -> str:
    """'value +/- U' for one element ('-' for U when the fit left it out)."""
    v = float(value)
    u_text = "-" if u is None or not np.isfinite(float(u)) else fmt(float(u), 2)
    return f"{fmt(v, digits)} &plusmn; {u_text}"


def _vector_table(rows: list[tuple[str, ArrayValue, str]]) -> Table:
    data: list[list[Any]] = [[_p(h) for h in ("Quantity", "x", "y", "z", "Units")]]
    for label, arr, units in rows:
        cells = [_p(_pm(v, u)) for v, u in zip(arr.value, arr.uncertainty_k2, strict=True)]
        data.append([_p(label), *cells, _p(units)])
    return fitted_table(data, WIDTH, grid_style())


def _matrix_table(title: str, arr: ArrayValue, units: str, digits: int = 6) -> Table:
    data: list[list[Any]] = [[_p(f"{title} ({units})"), _p("x"), _p("y"), _p("z")]]
    for i, a in enumerate(AXES):
        row_v, row_u = arr.value[i], arr.uncertainty_k2[i]
        assert isinstance(row_v, list) and isinstance(row_u, list)
        data.append([_p(f"row {a}"),
                     *[_p(_pm(v, u, digits)) for v, u in zip(row_v, row_u, strict=True)]])
    return fitted_table(data, WIDTH, grid_style())


def _misalignment_mrad(cal: CalibrationThreeAxis) -> Table:
    """M's off-diagonal over its row's diagonal, in mrad; the diagonal shows the raw scale
    error 1/M_ii - 1 in % (the same quantities the limits judge)."""
    m = np.asarray(cal.matrix.value, dtype=float)
    u = np.array(cal.matrix.uncertainty_k2, dtype=float)  # None (not fitted) becomes nan
    data: list[list[Any]] = [[_p("Misalignment (mrad); diagonal: raw scale error (%)"),
                              _p("x"), _p("y"), _p("z")]]
    for i, a in enumerate(AXES):
        cells = []
        for j in range(3):
            if i == j:
                cells.append(_p(_pm(1e2 * (1 / m[i, i] - 1), 1e2 * u[i, i] / m[i, i] ** 2, 4)))
            else:
                cells.append(_p(_pm(1e3 * m[i, j] / m[i, i], 1e3 * u[i, j] / abs(m[i, i]), 4)))
        data.append([_p(f"row {a}"), *cells])
    return fitted_table(data, WIDTH, grid_style())


def _judged(rec: RunRecord) -> str:
    rows = [m for m in rec.measurements if m.name.startswith(JUDGED_PREFIXES)]
    n_fail = sum(m.outcome == Outcome.FAIL for m in rows)
    n_marg = sum(m.outcome == Outcome.MARGINAL for m in rows)
    return (f"<b>Limits judged:</b> {len(rows)} per-axis values against the product's limits "
            f"(their rows in the Results table): {n_fail} failed, {n_marg} marginal.")


def _readback(rec: RunRecord, cal: CalibrationThreeAxis) -> str:
    programming = rec.analysis.programming
    if programming is None or not programming.programmed:
        why = (programming.reason if programming else None) or rec.reason
        return f"<b>Programming:</b> not programmed: {why.removeprefix('not programmed: ')}."
    text = {True: "PASSED (registers read back equal to the values written)",
            False: "FAILED (registers read back differ from the values written)",
            None: "not recorded"}[cal.readback_ok]
    rb = cal.readback or {}
    diffs = []
    for key in ("bias_dps", "matrix"):
        if key in rb:
            written = np.asarray(getattr(cal, key).value, dtype=float)
            diffs.append(float(np.max(np.abs(np.asarray(rb[key], dtype=float) - written))))
    largest = f"; largest difference of b and M read back: {fmt(max(diffs), 2)}" if diffs else ""
    return f"<b>Programming:</b> written; read-back check {text}{largest}."


def summary(rec: RunRecord) -> str | None:
    """The page-one calibration sentence of a three-axis record (None for single-axis)."""
    cal = three_axis_block(rec)
    if cal is None:
        return None
    programming = rec.analysis.programming
    if programming is None or not programming.programmed:
        return "No calibration was written to the part"
    rb = {True: "read-back PASSED", False: "read-back FAILED",
          None: "read-back not recorded"}[cal.readback_ok]
    return ("Three-axis calibration written: bias vector, correction matrix, g-sensitivity"
            + (" and per-axis temperature and supply coefficients" if cal.temp_supply_fitted
               else "") + f" (k = 2 uncertainties below); {rb}")


def three_axis(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    cal = three_axis_block(rec) if rec is not None else None
    if rec is None or cal is None:
        return []
    story: list[Flowable] = [
        Paragraph("Three-axis calibration written to the part", H2),
        Paragraph(
            "Model: raw = M<sup>-1</sup> D(T, V) w + b(T, V) + G a, with D = diag(1 + sT dT + "
            "sV dV) and b(T, V) = b + bT dT + bV dV per axis; the part's corrected rate is "
            "D<sup>-1</sup> M (raw - b(T, V) - G a). dT = die temperature - "
            f"{fmt(cal.reference_temperature_c)} C, dV = supply - {fmt(cal.reference_supply_v)}"
            " V. Each value is shown &plusmn; its expanded uncertainty (k = 2, about 95 %).",
            BODY),
        _vector_table([("Bias b", cal.bias_dps, "deg/s")]),
    ]
    story += [_matrix_table("Correction matrix M", cal.matrix, "1"),
              _misalignment_mrad(cal),
              _matrix_table("g-sensitivity G", cal.g_sensitivity_dps_per_mps2,
                            "deg/s per m/s<sup>2</sup>", 4)]
    if cal.temp_supply_fitted:
        story.append(_vector_table([(label, getattr(cal, key), units)
                                    for key, label, units in PER_AXIS]))
    else:
        story.append(Paragraph("Temperature and supply coefficients not fitted (one condition):"
                               " b and M are the part's at the measured die temperature "
                               f"{fmt(cal.mean_die_temperature_c, 4)} C and supply "
                               f"{fmt(cal.mean_supply_v, 4)} V.", NOTE))
    fit = ""
    if cal.fit_chi2 is not None and cal.fit_dof:
        fit = f" Fit: chi-square {fmt(cal.fit_chi2, 4)} on {cal.fit_dof} degrees of freedom."
    story.append(Paragraph(_judged(rec) + " " + _readback(rec, cal) + fit, BODY))
    return [KeepTogether(story[:3])] + story[3:]
