"""The lot report: yield, failure pareto, per-measurement histograms with limits and Cpk,
and the trend of the written bias and scale over time, all from the results database.

`render_lot_report(db, out, issued=..., since=..., product=..., verdict=..., serial=...)`
writes the PDF and returns a `LotSummary` with the figures it printed, so callers and tests
can check them. "Issued" is when the report was made (default now); give `issued` to make
the same bytes again from the same database content.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, KeepTogether, Paragraph, Spacer, Table, TableStyle

from reports import lot_stats, lot_three_axis
from reports.charts import LIMIT_RED, PALETTE, Chart, bar_chart, message_box
from reports.lot_rows import LotRows, MeasurementRow, RunRow
from reports.pdfdoc import PageFurniture, build_pdf, page_count, parse_utc, write_atomic
from reports.styles import (
    BODY,
    CELL,
    FAIL_ROW,
    FONT_BOLD,
    H1,
    H2,
    MARGINAL_AMBER,
    NOTE,
    escape,
    fmt,
    grid_style,
    titled,
    unit_label,
)
from reports.table_fit import fitted_table

FULL_W = 182 * mm
HALF_W = 90 * mm


@dataclass(frozen=True)
class LotSummary:
    path: Path
    yields: lot_stats.YieldSummary
    pareto: list[tuple[str, int]]
    capabilities: list[lot_stats.Capability]
    pages: int


def _p(text: object) -> Paragraph:
    return Paragraph(escape(text), CELL)


def _filters_text(filters: dict[str, object]) -> str:
    given = [f"{k} = {v}" for k, v in filters.items() if v not in (None, "")]
    return ", ".join(given) if given else "none (every run in the database)"


def _summary_table(y: lot_stats.YieldSummary) -> Table:
    yf = y.yield_fraction
    rows = [
        ["Runs", "Parts (serials)", "PASS", "FAIL", "ERROR", "ABORTED", "Yield"],
        [str(y.runs), str(y.parts), str(y.passed), str(y.failed), str(y.errors),
         str(y.aborted), f"{yf * 100:.1f} %" if yf is not None else "n/a"],
    ]
    t = Table(rows, colWidths=[26 * mm] * 7)
    style = grid_style()
    style.add("FONT", (0, 1), (-1, 1), FONT_BOLD, 11)
    style.add("ALIGN", (0, 0), (-1, -1), "CENTER")
    t.setStyle(style)
    return t


def _capability_table(caps: list[lot_stats.Capability]) -> Table:
    rows: list[list[str | Paragraph]] = [[_p(h) for h in (
        "Measurement", "Units", "n", "Mean", "Sigma (n-1)", "LSL", "USL", "Cpk")]]
    style = grid_style()
    for i, c in enumerate(caps, start=1):
        # numbers as plain strings, never broken; table_fit sizes every column to its content
        rows.append([_p(c.label + (" *" if c.limits_varied else "")), _p(unit_label(c.units)),
                     str(c.n), fmt(c.mean), fmt(c.sigma, 3), fmt(c.low), fmt(c.high),
                     _cpk_text(c)])
        if c.cpk is not None and c.cpk < 1.0:
            style.add("BACKGROUND", (0, i), (-1, i), FAIL_ROW)
        elif c.cpk is not None and c.cpk < 1.33:
            style.add("BACKGROUND", (0, i), (-1, i), MARGINAL_AMBER)
    return fitted_table(rows, FULL_W, style, repeatRows=1)


def _cpk_text(c: lot_stats.Capability) -> str:
    return f"too few (n < {lot_stats.MIN_CPK_N})" if c.too_few else fmt(c.cpk, 3)


def _histogram(c: lot_stats.Capability) -> Flowable:
    title = titled(c.label, c.units)
    if c.n < 2:
        return message_box(HALF_W, 55 * mm, title, f"Not drawn: {c.n} value(s) in the lot.")
    values = np.asarray(c.values)
    lo, hi = float(values.min()), float(values.max())
    if hi <= lo:
        lo, hi = lo - 0.5 * (abs(lo) or 1), hi + 0.5 * (abs(hi) or 1)
    bins = int(np.clip(math.ceil(math.sqrt(c.n)), 5, 30))
    counts, edges = np.histogram(values, bins=bins, range=(lo, hi))
    xs = [lo, hi] + [v for v in (c.low, c.high) if v is not None]
    span = max(xs) - min(xs)
    chart = Chart(HALF_W, 55 * mm, title=title, x_label=titled(c.name, c.units),
                  y_label="runs", x_range=(min(xs) - 0.04 * span, max(xs) + 0.04 * span))
    chart.bars(edges, counts, PALETTE[0], f"n = {c.n}")
    if c.low is not None:
        chart.vline(c.low, LIMIT_RED, "limits", dash=None, width=1.0)
    if c.high is not None:
        chart.vline(c.high, LIMIT_RED, None if c.low is not None else "limit", dash=None,
                    width=1.0)
    if c.mean is not None:
        chart.vline(c.mean, PALETTE[2], f"mean {fmt(c.mean, 4)}, sigma {fmt(c.sigma, 3)}, "
                    f"Cpk {_cpk_text(c)}", dash=(3, 2))
    return chart.drawing()


def _pairs(items: list[Flowable]) -> list[Flowable]:
    out: list[Flowable] = []
    for i in range(0, len(items), 2):
        row = items[i:i + 2] + ([Spacer(1, 1)] if len(items[i:i + 2]) == 1 else [])
        t = Table([row], colWidths=[HALF_W + 1 * mm, HALF_W])
        t.setStyle(TableStyle([("LEFTPADDING", (0, 0), (-1, -1), 0),
                               ("RIGHTPADDING", (0, 0), (-1, -1), 0),
                               ("VALIGN", (0, 0), (-1, -1), "TOP")]))
        out.append(t)
    return out


def _distributions(caps: list[lot_stats.Capability]) -> list[Flowable]:
    """Histograms of the measurements with 2 or more values; one note for all the others
    (a one-run lot would otherwise give pages of 'Not drawn' boxes)."""
    head = Paragraph("Distributions with limits", H2)
    hist = _pairs([_histogram(c) for c in caps if c.n >= 2])
    few = [c for c in caps if c.n < 2]
    story: list[Flowable] = [KeepTogether([head, hist[0]]), *hist[1:]] if hist else [head]
    if few and not hist:
        story.append(Paragraph("No histogram drawn: no measurement has 2 or more values from "
                               "completed runs in this lot.", NOTE))
    elif few:
        names = ", ".join(c.label for c in few[:8]) + (
            f" and {len(few) - 8} more" if len(few) > 8 else "")
        story.append(Paragraph(escape(f"Not drawn (fewer than 2 values in the lot): {names}."),
                               NOTE))
    return story


def trend_axis(times: list[datetime]) -> tuple[list[float], str]:
    """x values and label for a trend: hours since the first start, or the run's index in
    start order when every run has the same start time (hours would all be 0, a vertical
    line)."""
    t0 = min(times)
    if max(times) == t0:
        return ([float(i) for i in range(1, len(times) + 1)],
                f"run number (all runs started {t0:%Y-%m-%d %H:%M:%S} UTC)")
    return [(t - t0).total_seconds() / 3600 for t in times], f"hours since {t0:%Y-%m-%d %H:%M} UTC"


def _trend(runs: list[RunRow]) -> list[Flowable]:
    pts: list[tuple[datetime, RunRow]] = []
    for r in runs:
        t = parse_utc(r.started_utc)
        if t is not None and r.verdict in lot_stats.COMPLETED:
            pts.append((t, r))
    pts.sort(key=lambda p: p[0])
    if len(pts) < 2:
        return [Paragraph(f"Not drawn: {len(pts)} completed run(s) with a start time; a trend "
                          "needs 2 or more.", NOTE)]
    charts: list[Flowable] = []
    missing: list[str] = []
    for key, label, units in (("bias_dps", "Bias written to the part", "deg/s"),
                              ("scale", "Scale written to the part", "1")):
        mine = [(t, float(v)) for t, r in pts if (v := r.calibration.get(key)) is not None]
        if len(mine) < 2:
            missing.append(f"{key} ({len(mine)} run(s) with a written value)")
            continue
        xs, x_label = trend_axis([t for t, _v in mine])
        vals = [v for _t, v in mine]
        ch = Chart(HALF_W, 55 * mm, title=label, x_label=x_label, y_label=titled(key, units))
        ch.line(xs, vals, PALETTE[0], width=0.4)
        ch.scatter(xs, vals, PALETTE[0], size=1.8)
        ch.hline(float(np.mean(vals)), PALETTE[2], "lot mean", dash=(3, 2))
        charts.append(ch.drawing())
    story = _pairs(charts)
    if missing:
        story.append(Paragraph(escape("Not drawn: " + "; ".join(missing) + "."), NOTE))
    return story


def _run_list(runs: list[RunRow]) -> Table:
    heads = ("Run", "Serial", "Started (UTC)", "Verdict", "Failed / reason")
    rows: list[list[str | Paragraph]] = [[_p(h) for h in heads]]
    style = grid_style()
    for i, r in enumerate(runs, start=1):
        why = ", ".join(r.failed_measurements) or r.reason
        # Plain strings where the text is short: a 500-run list stays fast to lay out.
        rows.append([r.run_id if len(r.run_id) <= 36 else _p(r.run_id),
                     r.serial if len(r.serial) <= 16 else _p(r.serial),
                     r.started_utc.replace("+00:00", ""),
                     r.verdict + (" (sim)" if r.simulated else ""),
                     (why or "-") if len(why) <= 28 else _p(why)])
        if r.verdict != "PASS":
            style.add("BACKGROUND", (0, i), (-1, i), FAIL_ROW)
    return fitted_table(rows, FULL_W, style, repeatRows=1)


def _coverage_text(db: LotRows, runs: list[RunRow], filters: dict[str, object]) -> str:
    """Which runs the report covers: the filters, the runs' time span, the database."""
    where = f"Database: {db.path}."
    if not runs:
        return f"No run matches the filters ({_filters_text(filters)}). {where}"
    finished = [t for r in runs if (t := parse_utc(r.finished_utc)) is not None]
    newest = f"; newest finished {max(finished):%Y-%m-%d %H:%M:%S} UTC" if finished else ""
    return (f"Filters: {_filters_text(filters)}. Covers the {len(runs)} run(s) they select, "
            f"listed under Runs at the end: started from {runs[0].started_utc} to "
            f"{runs[-1].started_utc}{newest}. {where}")


def build_lot(db: LotRows, issued: datetime | None = None, include_simulated: bool = False,
              **filters: object) -> tuple[list[Flowable], LotSummary, PageFurniture]:
    """The lot report's story; `issued` (default now) is the date printed and stamped.
    Simulated runs (a bench simulator, no part) are left out unless include_simulated, as
    on the line's dashboard; the report says how many were."""
    issued = (issued or datetime.now(UTC)).astimezone(UTC).replace(microsecond=0)
    every = db.runs(**filters)
    runs = lot_stats.production_runs(every, include_simulated)
    kept = {r.run_id for r in runs}
    rows: list[MeasurementRow] = [m for m in db.measurement_values(**filters)
                                  if m.run_id in kept]
    y = lot_stats.yield_summary(runs)
    pareto = lot_stats.failure_pareto(rows)
    caps = [lot_stats.capability(n, rows, c) for n, c in lot_stats.measurement_keys(rows)]
    story: list[Flowable] = [
        Paragraph("Lot report - MEMS gyroscope calibration", H1),
        Paragraph(f"Issued {issued:%Y-%m-%d %H:%M:%S} UTC (when this report was made).", BODY),
        Paragraph(escape(_coverage_text(db, runs, filters)), BODY),
        Spacer(1, 3 * mm),
        _summary_table(y),
        Paragraph("Yield = PASS / (PASS + FAIL); ERROR and ABORTED runs are station problems, "
                  "listed but not counted in the yield.", NOTE),
    ]
    sims = sum(r.simulated for r in runs)
    if sims:
        story.append(Paragraph(f"{sims} of {len(runs)} runs used the SIMULATED bench "
                               "(included on request: these numbers are not production).",
                               BODY))
    if left_out := len(every) - len(runs):
        story.append(Paragraph(f"{left_out} simulated run(s) left out (a bench simulator, no "
                               "part; include them with --include-simulated).", BODY))
    story.append(Paragraph("Failure pareto (runs failing each measurement)", H2))
    if pareto:
        total = max(y.failed, 1)
        story.append(bar_chart(
            FULL_W, 62 * mm, [n for n, _ in pareto], [c for _, c in pareto],
            title="Failures by measurement (count, % of failed runs)", y_label="failing runs",
            value_labels=[f"{c} ({c / total * 100:.0f} %)" for _, c in pareto]))
    else:
        story.append(Paragraph("No failing measurement in this lot.", BODY))
    story += [Paragraph("Capability", H2), _capability_table(caps), Paragraph(
        "Over completed runs (PASS or FAIL). Sigma = sample standard deviation (n - 1) of all "
        "values in the lot (overall sigma, so strictly Ppk). Cpk = min(USL - mean, mean - LSL) "
        "/ (3 sigma); one-sided when a limit is missing; none below "
        f"{lot_stats.MIN_CPK_N} values (too few to tell). Red: Cpk < 1.0, amber: Cpk < 1.33. "
        "* limits changed within the lot; the newest run's limits are used.", NOTE)]
    story += _distributions(caps)
    elements = [e for e in db.calibration_elements(**filters) if e.run_id in kept]
    story += lot_three_axis.three_axis_section(elements, runs)  # none for single-axis parts
    trend = _trend(runs)
    story += [KeepTogether([Paragraph("Trend of the calibration written", H2), trend[0]])]
    story += trend[1:]
    story += [Paragraph("Runs", H2), _run_list(runs)]
    furniture = PageFurniture(
        title="Lot report",
        identity=f"{y.runs} run{'' if y.runs == 1 else 's'} | yield "
                 + (f"{y.yield_fraction * 100:.1f} %" if y.yield_fraction is not None else "n/a"),
        simulated=sims > 0,
        document_time=issued,
        subject="lot report",
    )
    summary = LotSummary(Path(), y, pareto, caps, 0)
    return story, summary, furniture


def render_lot_report(db: LotRows, out: Path, issued: datetime | None = None,
                      include_simulated: bool = False, **filters: object) -> LotSummary:
    """Write the lot report PDF for the runs matching the filters (see ResultsDB.runs),
    simulated runs left out unless include_simulated.

    `issued` is the issue time printed on every page (default now); pass the same value to
    get the same bytes again.
    """
    story, summary, furniture = build_lot(db, issued, include_simulated, **filters)
    data = build_pdf(story, furniture)
    write_atomic(Path(out), data)
    return LotSummary(Path(out), summary.yields, summary.pareto, summary.capabilities,
                      page_count(data))
