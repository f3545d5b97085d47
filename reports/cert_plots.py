"""The certificate's plots, drawn as vector graphics from raw.h5 and record.analysis.

- stop method: rate versus time per condition, like the article's Figure 4, with the static
  (bias) windows and the integration windows shaded;
- rate table: output versus input and the residuals from the fitted line, per condition;
- Allan deviation with the fitted noise terms (angle random walk, bias instability);
- the part's own temperature during stabilisation with the stability criterion.

reports/cert_figures.py chooses which of them a certificate shows (with the ramp's,
reports/cert_ramp_chart.py).

Any plot whose data is missing is replaced by a box saying what is missing (the sections
read are procedures/runtime/results.py's models); none of these functions raises on bad data.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
from reportlab.graphics.shapes import Drawing
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, KeepTogether, Paragraph, Table, TableStyle

from procedures.runtime.rawdata import RawData
from procedures.runtime.results import Analysis
from reports import record_keys
from reports.cert_inputs import CertificateInputs
from reports.charts import INTEGRATION_FILL, PALETTE, STATIC_FILL, Chart, message_box
from reports.styles import H2, NOTE, escape, fmt

log = logging.getLogger(__name__)

FULL_W = 182 * mm
HALF_W = 90 * mm


def _segments(raw: RawData, condition: str | None, kinds: tuple[str, ...]) -> list[tuple]:
    seg = raw["segments"]
    rows = []
    for i in range(len(seg["kind"])):
        if seg["kind"][i] in kinds and (condition is None or seg["condition"][i] == condition):
            rows.append((str(seg["condition"][i]), str(seg["kind"][i]), int(seg["index"][i]),
                         float(seg["start_s"][i]), float(seg["end_s"][i]),
                         float(seg["ref_rate_dps"][i])))
    return sorted(rows, key=lambda r: (r[3], r[2]))


def _conditions_with(raw: RawData, kinds: tuple[str, ...]) -> list[str]:
    seg = raw["segments"]
    return sorted({str(c) for c, k in zip(seg["condition"], seg["kind"], strict=True)
                   if k in kinds})


def _window(raw: RawData, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = raw["samples"]
    t = s["time_s"]
    sel = (t >= t0) & (t <= t1)
    return t[sel], s["rate_dps"][sel], s["temp_c"][sel]


def safe_plot(title: str, width: float, height: float, build: Callable[[], list[Flowable]]
          ) -> list[Flowable]:
    try:
        return build()
    except record_keys.MissingAnalysisError as exc:
        return [message_box(width, height, title, f"Not drawn: {exc}.")]
    except Exception as exc:  # a plot must never stop a certificate being issued
        log.exception("plot %r failed", title)
        return [message_box(width, height, title,
                            f"Not drawn: {type(exc).__name__}: {exc}. Report this to the "
                            "station software team with the run folder.")]


def stop_method(inputs: CertificateInputs) -> list[Flowable]:
    story: list[Flowable] = [Paragraph("Stop method: rate record (as the article's Figure 4)",
                                       H2)]
    title = "Stop method"

    def build() -> list[Flowable]:
        raw = inputs.raw
        if raw is None:
            raise record_keys.MissingAnalysisError("the raw data file could not be read")
        rec = inputs.record
        summaries = record_keys.stop_method(rec.analysis) if rec else {}
        conds = sorted(set(_conditions_with(raw, ("stop_static", "stop_move"))) | set(summaries))
        if not conds:
            raise record_keys.MissingAnalysisError(
                "raw.h5 has no stop_static/stop_move segments and record.analysis has no "
                "'stop_method'")
        out: list[Flowable] = []
        for cond in conds[:4]:
            out.append(_stop_chart(raw, cond, summaries.get(cond)))
        if len(conds) > 4:
            out.append(Paragraph(f"{len(conds) - 4} more conditions not drawn.", NOTE))
        return out + _ramp_stop_notes(rec.analysis if rec else None)

    return story + safe_plot(title, FULL_W, 52 * mm, build)


def _ramp_stop_notes(analysis: Analysis | None) -> list[Flowable]:
    """A line per ramp end: the stop scale against the ramp fit's law there."""
    if analysis is None or analysis.ramp_stop is None:
        return []
    return [Paragraph(escape(
        f"{e.label}: die {fmt(e.die_temp_c, 4)} C (element {fmt(e.element_temp_c, 4)} C), "
        f"{fmt(e.supply_v, 4)} V: stop scale {fmt(e.stop.scale, 7)} (u {fmt(e.stop.u_scale, 2)})"
        f", the ramp fit's law {fmt(e.ramp_scale, 7)} (u {fmt(e.u_ramp_scale, 2)}), E_n "
        f"{fmt(e.normalised_difference, 3)}"), NOTE) for e in analysis.ramp_stop.ends]


def _stop_chart(raw: RawData, cond: str, summary: record_keys.StopSummary | None) -> Flowable:
    segs = _segments(raw, cond, ("stop_static", "stop_move"))
    static = (summary.static_windows if summary and summary.static_windows
              else [(r[3], r[4]) for r in segs if r[1] == "stop_static"])
    integ = (summary.integration_windows if summary and summary.integration_windows
             else [(r[3], r[4]) for r in segs if r[1] == "stop_move"])
    spans = static + integ
    if not spans:
        return message_box(FULL_W, 48 * mm, f"Stop method {cond}",
                           f"Not drawn: no stop-method windows for condition {cond}.")
    t0 = min(a for a, _ in spans) - 0.5
    t1 = max(b for _, b in spans) + 0.5
    t, rate, _ = _window(raw, t0, t1)
    if t.size < 2:
        return message_box(FULL_W, 48 * mm, f"Stop method {cond}",
                           f"Not drawn: raw.h5 holds no samples between {t0:.1f} s and "
                           f"{t1:.1f} s for condition {cond}.")
    origin = float(t[0])
    chart = Chart(FULL_W, 48 * mm, title=f"Stop method, condition {cond} "
                  f"(t = 0 at {origin:.1f} s fixture time)",
                  x_label="time (s)", y_label="rate (deg/s)")
    for i, (a, b) in enumerate(static):
        chart.shade_x(a - origin, b - origin, STATIC_FILL,
                      "static (bias) window" if i == 0 else None)
    for i, (a, b) in enumerate(integ):
        chart.shade_x(a - origin, b - origin, INTEGRATION_FILL,
                      "integration window" if i == 0 else None)
    chart.line(t - origin, rate, PALETTE[0], "gyro output", width=0.6)
    items = [chart.drawing()]
    if summary is not None:
        moves = "; ".join(
            f"move {i + 1}: {fmt(m.measured_angle_deg)} deg, scale correction "
            f"{fmt(m.scale_correction)}" for i, m in enumerate(summary.moves)
            if m.measured_angle_deg is not None or m.scale_correction is not None)
        items.append(Paragraph(escape(
            f"{cond}: bias {fmt(summary.bias_dps)} deg/s (correction "
            f"{fmt(-summary.bias_dps if summary.bias_dps is not None else None)} deg/s); "
            f"{moves or 'no moves recorded'}; scale correction {fmt(summary.scale_correction)}"),
            NOTE))
    return KeepTogether(items)


def _rate_points_from_raw(raw: RawData) -> list[record_keys.RatePoints]:
    out = []
    for cond in _conditions_with(raw, ("plateau",)):
        rin, rout = [], []
        for _c, _k, _i, a, b, ref in _segments(raw, cond, ("plateau",)):
            _t, rate, _ = _window(raw, a, b)
            if rate.size:
                rin.append(ref)
                rout.append(float(np.mean(rate)))
        if len(rin) >= 2:
            slope, icpt = np.polyfit(rin, rout, 1)
            resid = [o - (slope * i + icpt) for i, o in zip(rin, rout, strict=True)]
            out.append(record_keys.RatePoints(cond, rin, rout, resid, float(slope), float(icpt),
                                              from_raw=True))
    if not out:
        raise record_keys.MissingAnalysisError(
            "record.analysis has no 'rate_table' and raw.h5 has no plateau segments")
    return out


def by_input_rate(rate_in_dps: list[float], values: list[float]) -> tuple[list[float],
                                                                         list[float]]:
    """Both lists reordered by increasing input rate (stable for repeated rates).

    Plateaus are measured in the procedure's order (e.g. 0, +100, -100, +300, ...); a line
    through the residuals in that order zig-zags across the chart.
    """
    order = sorted(range(len(rate_in_dps)), key=lambda k: rate_in_dps[k])
    return [rate_in_dps[k] for k in order], [values[k] for k in order]


def rate_table_charts(points: list[record_keys.RatePoints]) -> tuple[Chart, Chart]:
    """Output versus input with the fitted lines, and the residuals per condition."""
    left = Chart(HALF_W, 62 * mm, title="Output versus input", x_label="table rate (deg/s)",
                 y_label="gyro output (deg/s)")
    right = Chart(HALF_W, 62 * mm, title="Residual from the fitted line",
                  x_label="table rate (deg/s)", y_label="residual (deg/s)")
    for i, p in enumerate(points):
        colour = PALETTE[i % len(PALETTE)]
        left.scatter(p.rate_in_dps, p.rate_out_dps, colour, p.condition, size=2.6)
        if p.scale is not None and p.bias_dps is not None and p.rate_in_dps:
            xs = [min(p.rate_in_dps), max(p.rate_in_dps)]
            left.line(xs, [p.scale * x + p.bias_dps for x in xs], colour, width=0.4)
        if p.residual_dps:
            rin, resid = by_input_rate(p.rate_in_dps, p.residual_dps)
            right.line(rin, resid, colour, p.condition, width=0.5)
            right.scatter(rin, resid, colour, size=2.2)
    right.hline(0.0, dash=None, width=0.4)
    return left, right


def rate_table(inputs: CertificateInputs) -> list[Flowable]:
    story: list[Flowable] = [Paragraph("Rate table: output versus input, residuals", H2)]

    def build() -> list[Flowable]:
        rec = inputs.record
        try:
            points = record_keys.rate_table(rec.analysis if rec else Analysis())
        except record_keys.MissingAnalysisError:
            if inputs.raw is None:
                raise
            points = _rate_points_from_raw(inputs.raw)
        left, right = rate_table_charts(points)
        grid = Table([[left.drawing(), right.drawing()]], colWidths=[HALF_W + 1 * mm, HALF_W])
        grid.setStyle(TableStyle([("LEFTPADDING", (0, 0), (-1, -1), 0),
                                  ("RIGHTPADDING", (0, 0), (-1, -1), 0)]))
        lines = [f"{p.condition}: scale {fmt(p.scale, 6)}, bias {fmt(p.bias_dps)} deg/s, "
                 f"largest residual {fmt(max((abs(r) for r in p.residual_dps), default=None), 3)}"
                 f" deg/s" for p in points]
        note = " (computed from raw.h5 plateau means for display; record.analysis has no "\
               "'rate_table')" if points[0].from_raw else ""
        return [grid, Paragraph(escape("; ".join(lines) + note), NOTE)]

    return story + safe_plot("Rate table", FULL_W, 60 * mm, build)


def allan(inputs: CertificateInputs) -> list[Flowable]:
    story: list[Flowable] = [Paragraph("Noise: Allan deviation", H2)]

    def build() -> list[Flowable]:
        a = record_keys.allan(inputs.record.analysis if inputs.record else Analysis())
        chart = Chart(HALF_W + 20 * mm, 62 * mm, title=f"Allan deviation {a.condition}".strip(),
                      x_label="averaging time tau (s)", y_label="Allan deviation (deg/s)",
                      log_x=True, log_y=True)
        measured = [v for v in a.adev_dps if v > 0 and math.isfinite(v)]
        if measured:  # the fitted-term lines must not stretch the axes away from the data
            chart.y_range = (10 ** math.floor(math.log10(min(measured) / 2)),
                             10 ** math.ceil(math.log10(max(measured) * 1.5)))
        chart.line(a.tau_s, a.adev_dps, PALETTE[0], "measured", width=0.8)
        chart.scatter(a.tau_s, a.adev_dps, PALETTE[0], size=1.8)
        tau = np.asarray(a.tau_s)
        if a.arw_deg_per_sqrt_h is not None:
            n_dps_rt_s = a.arw_deg_per_sqrt_h / 60.0  # deg/sqrt(h) -> (deg/s) * sqrt(s)
            chart.line(tau, n_dps_rt_s / np.sqrt(tau), PALETTE[1],
                       f"ARW {fmt(a.arw_deg_per_sqrt_h, 3)} deg/sqrt(h)", dash=(3, 2))
        if a.bias_instability_deg_per_h is not None and a.bias_instability_deg_per_h <= 0:
            chart.title += " (bias instability not resolved: record too short)"
        elif a.bias_instability_deg_per_h is not None:
            floor = 0.664 * a.bias_instability_deg_per_h / 3600.0
            chart.hline(floor, PALETTE[2],
                        f"bias instability {fmt(a.bias_instability_deg_per_h, 3)}"
                        " deg/h (x 0.664)", dash=(1, 2))
        rrw = a.rate_random_walk_deg_per_h_per_sqrt_h
        if rrw is not None and rrw > 0:
            k_dps = rrw / (3600.0 * 60.0)  # deg/h/sqrt(h) -> (deg/s)/sqrt(s)
            chart.line(tau, k_dps * np.sqrt(tau / 3.0), PALETTE[3],
                       f"RRW {fmt(rrw, 3)} deg/h/sqrt(h)", dash=(4, 1, 1, 1))
        text = ("Overlapping Allan deviation of the static record (IEEE 952). The angle random "
                "walk line is N/sqrt(tau), read at tau = 1 s; the bias instability floor is "
                "0.664 B; rate random walk, when resolved, is K sqrt(tau/3).")
        if a.rate_random_walk_deg_per_h_per_sqrt_h:
            text += f" Rate random walk {fmt(a.rate_random_walk_deg_per_h_per_sqrt_h, 3)} "\
                    "deg/h/sqrt(h)."
        return [chart.drawing(), Paragraph(escape(text), NOTE)]

    return story + safe_plot("Allan deviation", FULL_W, 50 * mm, build)


def stabilisation(inputs: CertificateInputs) -> list[Flowable]:
    story: list[Flowable] = [Paragraph("Thermal stabilisation (part's own sensor)", H2)]

    def build() -> list[Flowable]:
        raw = inputs.raw
        if raw is None:
            raise record_keys.MissingAnalysisError("the raw data file could not be read")
        rec = inputs.record
        crit = record_keys.stability(rec.analysis) if rec else {}
        tts = {c.name: c.time_to_stability_s for c in rec.conditions} if rec else {}
        conds = _conditions_with(raw, ("stabilise",))
        if not conds:
            raise record_keys.MissingAnalysisError("raw.h5 has no segments of kind stabilise")
        left = Chart(HALF_W, 62 * mm, title="Die temperature", x_label="time from start (s)",
                     y_label="die temperature (C)")
        right = Chart(HALF_W, 62 * mm, title="Deviation from settled value, criterion",
                      x_label="time from start (s)", y_label="die temp - final (C)")
        tol = None
        for i, cond in enumerate(conds):
            colour = PALETTE[i % len(PALETTE)]
            segs = _segments(raw, cond, ("stabilise",))
            a, b = segs[0][3], segs[-1][4]
            t, _rate, temp = _window(raw, a, b)
            if t.size < 2:
                continue
            left.line(t - a, temp, colour, cond, width=0.7)
            right.line(t - a, temp - temp[-1], colour, cond, width=0.7)
            c = crit.get(cond)
            when = (c.time_to_stability_s if c and c.time_to_stability_s is not None
                    else tts.get(cond))
            if when is not None and math.isfinite(when):
                left.vline(when, colour, dash=(2, 2), width=0.6)
                right.vline(when, colour, dash=(2, 2), width=0.6)
            if c and c.band_c is not None:
                tol = c.band_c / 2
        if tol is not None:
            right.band_y(-tol, tol, STATIC_FILL, f"criterion band {fmt(2 * tol)} C")
            right.y_range = (-8 * tol, 8 * tol)  # zoomed on the criterion; the left plot shows all
            right.title = f"Deviation from settled value (zoom +/-{fmt(8 * tol)} C)"
        grid = Table([[left.drawing(), right.drawing()]], colWidths=[HALF_W + 1 * mm, HALF_W])
        grid.setStyle(TableStyle([("LEFTPADDING", (0, 0), (-1, -1), 0),
                                  ("RIGHTPADDING", (0, 0), (-1, -1), 0)]))
        note = ("Dashed vertical lines: the time each condition was declared stable; the "
                "criterion is judged over the window just before it (see Test conditions). "
                + ("" if crit else "record.analysis has no 'stability' criterion; only the "
                   "times to stability from record.conditions are marked."))
        return [grid, Paragraph(escape(note), NOTE)]

    return story + safe_plot("Thermal stabilisation", FULL_W, 60 * mm, build)


__all__ = ["Drawing", "allan", "rate_table", "safe_plot", "stabilisation", "stop_method"]
