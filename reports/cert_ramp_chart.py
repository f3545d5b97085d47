"""The ramp calibration's chart (step ramp_calibration): the part's die temperature over the
ramp with its fitted plateaus marked, heating and cooling, beside the fit's residual per
plateau against the die temperature.

The temperature line is the part's own sensor from raw.h5 (fixture time, the clock the
record's plateau times use); without raw.h5 the plateaus' means alone are drawn. Residuals
come from `record.analysis.ramp` (none when the fit refused the part or could not run).
"""

from __future__ import annotations

import math

import numpy as np
from reportlab.lib import colors
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, Paragraph, Table, TableStyle

from procedures.runtime.rawdata import RawData
from procedures.runtime.results import RampResults
from reports import record_keys
from reports.cert_inputs import CertificateInputs
from reports.cert_plots import FULL_W, HALF_W, safe_plot
from reports.charts import PALETTE, Chart, message_box
from reports.styles import H2, NOTE, escape, fmt

HEATING, COOLING = PALETTE[4], PALETTE[0]
SPAN_GREY = colors.HexColor("#8a8f96")
HEADING = "Ramp calibration: die temperature and fit residuals"


def _die_track(raw: RawData | None, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """The part's own sensor between two fixture times (empty without raw.h5)."""
    if raw is None:
        return np.array([]), np.array([])
    s = raw["samples"]
    t = np.asarray(s["time_s"], dtype=float)
    sel = (t >= t0) & (t <= t1)
    return t[sel], np.asarray(s["temp_c"], dtype=float)[sel]


def _split(values: list[float], heating: list[bool], want: bool) -> list[float]:
    return [v for v, h in zip(values, heating, strict=True) if h is want]


def temperature_chart(pts: record_keys.RampPoints, ramp: RampResults,
                      raw: RawData | None) -> Chart:
    origin = pts.time_s[0]
    chart = Chart(HALF_W, 66 * mm, title="Die temperature over the ramp",
                  x_label=f"time from the first plateau (min; t = 0 at {origin:.1f} s)",
                  y_label="die temperature, own sensor (C)")
    t, temp = _die_track(raw, origin - 10.0, pts.time_s[-1] + 10.0)
    if t.size >= 2:
        chart.line((t - origin) / 60.0, temp, colors.HexColor("#606060"), "die sensor",
                   width=0.5)
    minutes = [(x - origin) / 60.0 for x in pts.time_s]
    for want, colour, label in ((True, HEATING, "plateaus, die heating"),
                                (False, COOLING, "plateaus, die cooling")):
        chart.scatter(_split(minutes, pts.heating, want),
                      _split(pts.die_temp_c, pts.heating, want), colour, label, size=2.0)
    chart.hline(ramp.low_c, SPAN_GREY, f"span asked {fmt(ramp.low_c)} to {fmt(ramp.high_c)} C",
                dash=(3, 2), width=0.5)
    chart.hline(ramp.high_c, SPAN_GREY, dash=(3, 2), width=0.5)
    return chart


def residual_chart(pts: record_keys.RampPoints) -> Chart | None:
    """Residual per plateau against its die temperature; None when the fit gave none."""
    if all(r is None for r in pts.residual_dps):
        return None
    chart = Chart(HALF_W, 66 * mm, title="Fit residual per plateau",
                  x_label="die temperature, own sensor (C)", y_label="residual (deg/s)")
    resid = [math.nan if r is None else r for r in pts.residual_dps]
    for want, colour, label in ((True, HEATING, "die heating"), (False, COOLING, "die cooling")):
        chart.scatter(_split(pts.die_temp_c, pts.heating, want),
                      _split(resid, pts.heating, want), colour, label, size=2.0)
    chart.hline(0.0, dash=None, width=0.4)
    return chart


def _rms(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None]
    return math.sqrt(sum(x * x for x in v) / len(v)) if v else None


def ramp_note(pts: record_keys.RampPoints, ramp: RampResults, from_raw: bool) -> str:
    heat = [r for r, h in zip(pts.residual_dps, pts.heating, strict=True) if h]
    cool = [r for r, h in zip(pts.residual_dps, pts.heating, strict=True) if not h]
    text = (f"{len(heat)} heating and {len(cool)} cooling plateaus fitted; RMS residual "
            f"heating {fmt(_rms(heat), 3)} deg/s, cooling {fmt(_rms(cool), 3)} deg/s"
            f" (chi2/dof {fmt(ramp.chi2_per_dof, 3)}). ")
    text += ("The line is the part's own temperature sensor from raw.h5; each point is a "
             "plateau's mean." if from_raw else "raw.h5 could not be read: only the "
             "plateaus' mean die temperatures are drawn.")
    if ramp.refused:
        text += f" The part was refused: {ramp.refused}."
    return text


def ramp(inputs: CertificateInputs) -> list[Flowable]:
    story: list[Flowable] = [Paragraph(HEADING, H2)]

    def build() -> list[Flowable]:
        rec = inputs.record
        pts = record_keys.ramp(rec.analysis) if rec else None
        section = rec.analysis.ramp if rec else None
        if pts is None or section is None:
            raise record_keys.MissingAnalysisError("the record could not be read")
        left = temperature_chart(pts, section, inputs.raw)
        right = residual_chart(pts)
        drawn_right = right.drawing() if right is not None else message_box(
            HALF_W, 66 * mm, "Fit residual per plateau",
            "Not drawn: the fit gave no residuals (see Test conditions).")
        grid = Table([[left.drawing(), drawn_right]], colWidths=[HALF_W + 1 * mm, HALF_W])
        grid.setStyle(TableStyle([("LEFTPADDING", (0, 0), (-1, -1), 0),
                                  ("RIGHTPADDING", (0, 0), (-1, -1), 0)]))
        return [grid, Paragraph(escape(ramp_note(pts, section, inputs.raw is not None)),
                                NOTE)]

    return story + safe_plot("Ramp calibration", FULL_W, 60 * mm, build)
