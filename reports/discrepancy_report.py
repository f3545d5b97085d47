"""PDF report of a model-discrepancy run: where the gap was, which effect was named at each
step and why, residuals before and after, the gap against the noise floor at every step.
Vector charts only (reports/charts.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

import numpy as np
from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.units import mm
from reportlab.platypus import Paragraph, SimpleDocTemplate, Spacer, Table, TableStyle

from procedures.model.discrepancy import DiscrepancyResult, Iteration
from procedures.model.residuals import BinSummary
from procedures.model.twin import SimulationComparison
from reports.charts import PALETTE, Chart, nice_ticks
from reports.styles import BODY, CELL, HEADER_GREY, NOTE

H1 = BODY.clone("h1", fontSize=14, leading=17, fontName="Helvetica-Bold")
H2 = BODY.clone("h2", fontSize=11, leading=14, fontName="Helvetica-Bold", spaceBefore=6)
WIDTH = 180 * mm

PATTERN_AXIS = {
    "temperature": "temp_c",
    "supply": "supply_v",
    "rate": "rate_dps",
    "sign of rate": "rate_dps",
    "time since power-on": "time_since_power_on_s",
    "table angle": "angle_deg",
    "segment kind": "center_s",
}
AXIS_LABEL = {
    "temp_c": "die temperature (C)",
    "supply_v": "supply (V)",
    "rate_dps": "block mean rate (deg/s)",
    "time_since_power_on_s": "time since power-on (s)",
    "angle_deg": "table angle (deg)",
    "center_s": "time (s)",
}


def _table(rows: list[list[Any]], widths: list[float] | None = None) -> Table:
    data = [[Paragraph(str(c), CELL) for c in r] for r in rows]
    t = Table(data, colWidths=widths, repeatRows=1)
    t.setStyle(
        TableStyle(
            [
                ("BACKGROUND", (0, 0), (-1, 0), HEADER_GREY),
                ("GRID", (0, 0), (-1, -1), 0.25, colors.grey),
                ("VALIGN", (0, 0), (-1, -1), "TOP"),
            ]
        )
    )
    return t


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def step_axis_range(n_steps: int) -> tuple[float, float]:
    """x range for steps 0..n_steps on which the chart's round ticks are whole steps: the
    range is widened past the last step until nice_ticks spaces them 1, 2, 5, ... apart
    (a range under 2.5 steps wide, or 10.5 to 12.5, would give 0.5 or 2.5 spacing)."""
    lo, hi = -0.5, n_steps + 0.5
    while not all(float(t).is_integer() for t in nice_ticks(lo, hi)):
        hi += 0.5
    return lo, hi


def _gap_chart(res: DiscrepancyResult) -> Any:
    steps = np.arange(len(res.iterations) + 1, dtype=float)
    vals = [res.gap_initial_dps, *[it.gap_after_dps for it in res.iterations]]
    ch = Chart(WIDTH, 150, title="Gap at each step against the noise floor",
               x_label="step (0 = starting model; names in the table)", y_label="deg/s",
               log_y=True, x_range=step_axis_range(len(res.iterations)))
    ch.hline(res.noise_floor_dps, color=PALETTE[2], label="noise floor")
    ch.hline(1.5 * res.noise_floor_dps, label="1.5 x floor")
    ch.line(steps, vals, color=PALETTE[0], label="gap")
    ch.scatter(steps, vals, color=PALETTE[0], size=3)
    return ch.drawing()


def _gap_table(res: DiscrepancyResult) -> Table:
    f = res.noise_floor_dps
    rows: list[list[Any]] = [["step", "effect named", "gap before (deg/s)", "gap after (deg/s)",
                              "after / floor"]]
    rows.append(["0", f"(starting model {res.initial_model.name})", "",
                 _fmt(res.gap_initial_dps), f"{res.gap_initial_dps / f:.2f}"])
    for k, it in enumerate(res.iterations, start=1):
        rows.append([str(k), it.effect, _fmt(it.gap_before_dps), _fmt(it.gap_after_dps),
                     f"{it.gap_after_dps / f:.2f}"])
    return _table(rows)


def _allan_chart(res: DiscrepancyResult) -> Any:
    ch = Chart(WIDTH, 170, title="Allan deviation of the residual (constant-input windows) "
               "and the noise model",
               x_label="tau (s)", y_label="deg/s", log_x=True, log_y=True)
    if res.noise.tau_s.size:
        ch.scatter(res.noise.tau_s, res.noise.adev_dps, label="measured")
        ch.line(res.noise.tau_s, res.noise.sigma_dps(res.noise.tau_s), label="noise model")
    return ch.drawing()


def _residual_chart(res: DiscrepancyResult, x: np.ndarray, x_label: str, title: str,
                    before: np.ndarray, after: np.ndarray) -> Any:
    ch = Chart(WIDTH, 170, title=title, x_label=x_label, y_label="block-mean residual (deg/s)")
    f = res.noise_floor_dps
    ch.band_y(-f, f, label="+/- noise floor")
    ch.scatter(x, before, color=PALETTE[1], label="before", size=1.6)
    ch.scatter(x, after, color=PALETTE[0], label="after", size=1.6)
    return ch.drawing()


def _summary_rows(before: list[BinSummary], after: list[BinSummary]) -> list[list[Any]]:
    rows: list[list[Any]] = [["bin", "blocks", "mean before", "z before", "rms before",
                              "mean after", "z after", "rms after", "floor"]]
    after_by = {b.label: b for b in after}
    for b in before:
        a = after_by.get(b.label)
        rows.append([b.label, b.n_blocks, _fmt(b.mean_dps), f"{b.z:.1f}", _fmt(b.rms_dps),
                     _fmt(a.mean_dps) if a else "", f"{a.z:.1f}" if a else "",
                     _fmt(a.rms_dps) if a else "", _fmt(b.floor_dps)])
    return rows


MAX_CANDIDATE_ROWS = 12


def _iteration_story(res: DiscrepancyResult, k: int, it: Iteration) -> list[Any]:
    ev = it.evidence
    story: list[Any] = [Paragraph(f"Step {k}: named <b>{it.effect}</b>", H2)]
    params = ", ".join(
        f"{p} = {_fmt(v)}" + (f" &plusmn; {_fmt(it.uncertainties[p])}" if p in it.uncertainties
                              else "")
        for p, v in it.parameters.items()
    )
    runner = ev.get("runner_up")
    why = (
        f"Adding {it.effect} lowers chi<super>2</super> by {ev['delta_chi2']:.1f} "
        f"(F = {ev['f_statistic']:.1f}, Holm-adjusted p = {ev['p_holm']:.2g} against a "
        f"family-wise false-alarm rate of {ev['alpha_familywise']:g} over "
        f"{ev['n_candidates']} candidates; BIC change {ev['delta_bic']:.1f}). "
    )
    if runner:
        why += (f"Next best: {runner['effect']}, BIC {runner['delta_bic_vs_best']:.1f} worse. ")
    pat = ev["pattern"]
    why += (
        f"The residual pattern it explains shows against <i>{pat['variable']}</i> "
        f"(largest |z| of a bin {pat['worst_z_before']} before, {pat['worst_z_after']} after; "
        f"expected signature: {pat['expected']}). Gap {it.gap_before_dps:.4g} &rarr; "
        f"{it.gap_after_dps:.4g} deg/s against a floor of {res.noise_floor_dps:.4g} deg/s."
    )
    story += [Paragraph(why, BODY),
              Paragraph(f"Formula: {escape(it.formula)} (depends on: "
                        f"{', '.join(it.regressors)})", BODY),
              Paragraph(f"Parameters: {params}", BODY), Spacer(1, 3)]
    rows: list[list[Any]] = [["candidate", "delta chi2", "p (Holm)", "delta BIC", "significant"]]
    shown = it.candidates[:MAX_CANDIDATE_ROWS]
    if len(it.candidates) > len(shown):
        story.append(Paragraph(f"The {len(shown)} best of {len(it.candidates)} candidates "
                               "tested (catalog and library), by BIC:", NOTE))
    for c in shown:
        rows.append([c.effect, f"{c.delta_chi2:.1f}", f"{c.p_holm:.2g}", f"{c.delta_bic:.1f}",
                     "yes" if c.significant else "no"])
    story.append(_table(rows))
    axis = PATTERN_AXIS.get(pat["variable"], "center_s")
    x = getattr(res.blocks, axis)
    story.append(_residual_chart(res, x, AXIS_LABEL[axis],
                                 f"Residuals against {pat['variable']}, before and after step {k}",
                                 it.residual_before_dps, it.residual_after_dps))
    return story


def _simulation_chart(sim: SimulationComparison, residual: np.ndarray, title: str,
                      y_range: tuple[float, float]) -> Any:
    ch = Chart(WIDTH / 2 - 2 * mm, 170, title=title, x_label="time of the window (s)",
               y_label="measured - simulated (deg/s)", y_range=y_range)
    f = sim.noise_floor_dps
    ch.band_y(-f, f, label="+/- noise floor")
    ch.scatter(sim.center_s, residual, color=PALETTE[0], size=1.8, label="window")
    return ch.drawing()


def simulation_story(sim: SimulationComparison) -> list[Any]:
    """The comparison measurement-vs-simulation: gaps, and the residuals side by side."""
    f = sim.noise_floor_dps
    story: list[Any] = [
        Paragraph("The twin learns the part: measurement against simulation", H2),
        Paragraph(
            f"The run's procedure was run on the simulated bench with the starting model and "
            f"with the extended model as the part. Simulation gap (duration-weighted RMS over "
            f"{len(sim.keys)} window pieces, windows cut to at most 10 s, of measured minus "
            f"simulated mean): "
            f"<b>{sim.gap_before_dps:.4g} deg/s</b> with the starting model "
            f"({sim.gap_before_dps / f:.2f} x the noise floor), <b>{sim.gap_after_dps:.4g} "
            f"deg/s</b> with the extended model ({sim.gap_after_dps / f:.2f} x); noise floor "
            f"over the same windows {f:.4g} deg/s.", BODY),
    ]
    for note in sim.notes:
        story.append(Paragraph(f"Note: {escape(note)}", NOTE))
    both = np.concatenate([sim.residual_before_dps, sim.residual_after_dps, [-f, f]])
    lo, hi = float(np.min(both)), float(np.max(both))
    pad = 0.05 * (hi - lo) or f
    y_range = (lo - pad, hi + pad)  # one scale for both: the shrinking is seen at a glance
    row = [_simulation_chart(sim, sim.residual_before_dps, "Starting model as the twin",
                             y_range),
           _simulation_chart(sim, sim.residual_after_dps, "Extended model as the twin",
                             y_range)]
    story.append(Table([row], colWidths=[WIDTH / 2, WIDTH / 2]))
    return story


def build_story(res: DiscrepancyResult, title_data: str = "",
                simulation: SimulationComparison | None = None) -> list[Any]:
    n = res.noise
    story: list[Any] = [
        Paragraph("Model-discrepancy report", H1),
        Paragraph(f"Data: {escape(title_data)}", BODY),
        Paragraph(
            f"Starting model: <b>{res.initial_model.name}</b>. Final model: "
            f"<b>{res.final_model.name}</b>. Effects added: "
            f"{', '.join(res.effects_added) or 'none'}.", BODY),
        Paragraph(
            f"Gap {res.gap_initial_dps:.4g} deg/s at the start, {res.gap_final_dps:.4g} deg/s "
            f"at the end ({res.gap_final_dps / res.noise_floor_dps:.2f} x the noise floor of "
            f"{res.noise_floor_dps:.4g} deg/s). Noise measured from the data: ARW "
            f"{n.arw_deg_per_sqrt_h:.3g} deg/sqrt(h) (Allan deviation); bias wander between "
            f"windows (REML): flat level {n.floor_dps:.3g} deg/s (bias instability "
            f"{n.bias_instability_deg_per_h:.3g} deg/h), rate random walk "
            f"{n.rrw_deg_per_h_per_sqrt_h:.3g} deg/h/sqrt(h); "
            f"{res.blocks.count} averaging blocks.", BODY),
        Paragraph(
            "Gap: duration-weighted RMS of the block-mean residuals. Noise floor: the same RMS "
            "of what the measured noise alone leaves in a block mean about the record mean. "
            "See docs/discrepancy.md.", NOTE),
    ]
    for ns in res.not_separable:
        story.append(Paragraph(
            f"<b>Not separable:</b> {' / '.join(ns['effects'])} (BIC differences "
            f"{ns['delta_bic']}, signature correlation {ns['signature_correlation']}): "
            f"{ns['reason']}.", BODY))
    if res.unexplained_remains:
        story.append(Paragraph(
            f"<b>Warning:</b> {escape(res.unexplained_message)}.", BODY))
    if res.not_identifiable:
        story.append(Paragraph(
            f"Not identifiable from this data (no independent signature): "
            f"{', '.join(res.not_identifiable)}.", BODY))
    for note in res.notes:
        story.append(Paragraph(f"Note: {escape(note)}", NOTE))
    story += [Spacer(1, 4), _gap_chart(res), _gap_table(res), Spacer(1, 4),
              _allan_chart(res)]
    story.append(_residual_chart(res, res.blocks.center_s, "time (s)",
                                 "Residuals over the record: starting model vs final model",
                                 res.residual_initial_dps, res.residual_final_dps))
    if simulation is not None:
        story += simulation_story(simulation)
    for k, it in enumerate(res.iterations, start=1):
        story += _iteration_story(res, k, it)
    if not res.iterations:
        story.append(Paragraph("No candidate effect is significant: nothing was named.", H2))
    story.append(Paragraph("Where the gap was: residual summaries, start vs end", H2))
    for dim, before in res.summary_initial.items():
        story.append(Paragraph(f"by {dim}", BODY))
        story.append(_table(_summary_rows(before, res.summary_final.get(dim, []))))
    return story


def write_report(res: DiscrepancyResult, path: Path, title_data: str = "",
                 simulation: SimulationComparison | None = None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = SimpleDocTemplate(str(path), pagesize=A4, leftMargin=15 * mm, rightMargin=15 * mm,
                            topMargin=15 * mm, bottomMargin=15 * mm,
                            title="Model-discrepancy report", author="gyrocal station")
    doc.build(build_story(res, title_data, simulation))
    return path
