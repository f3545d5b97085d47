"""The tables of a certificate: header, traceability, conditions, results, calibration.

Each function takes the loaded inputs and returns platypus flowables. Everything the record
lacks is shown as '-' or a sentence saying it is not recorded; nothing here raises on a
sparse record.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import date, datetime
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from reportlab.lib import colors
from reportlab.lib.styles import ParagraphStyle
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, KeepTogether, Paragraph, Spacer, Table, TableStyle

from procedures.runtime.record import Calibration, Coefficient, Measurement, Outcome, RunRecord
from reports import cert_ramp, cert_three_axis, record_keys
from reports.cert_inputs import CertificateInputs
from reports.cert_safe_state import safe_state_box
from reports.pdfdoc import parse_utc
from reports.styles import (
    BODY,
    CELL,
    CELL_MONO,
    FAIL_ROW,
    FONT_BOLD,
    H1,
    H2,
    HEADER_GREY,
    MARGINAL_AMBER,
    NOTE,
    VERDICT_COLOURS,
    WARNING,
    bounded,
    escape,
    fmt,
    grid_style,
    unit_label,
    verdict_style,
    with_units,
)
from reports.table_fit import fitted_table

CONTENT_WIDTH = 182 * mm
CELL_BOLD = ParagraphStyle("cellbold", parent=CELL, fontName=FONT_BOLD)


def _p(text: object, style: ParagraphStyle = CELL) -> Paragraph:
    return Paragraph(escape(text), style)


def local_time_text(utc_text: str | None, tz_name: str) -> str:
    t = parse_utc(utc_text)
    if t is None:
        return "not recorded"
    if not tz_name:
        return "station time zone not recorded"
    try:
        local = t.astimezone(ZoneInfo(tz_name))
    except (ZoneInfoNotFoundError, ValueError):
        return f"unknown time zone {tz_name!r}"
    return f"{local:%Y-%m-%d %H:%M:%S} {local.tzname()} ({tz_name})"


def utc_text(text: str | None) -> str:
    t = parse_utc(text)
    return f"{t:%Y-%m-%d %H:%M:%S} UTC" if t else (text or "not recorded")


def failing(record: RunRecord) -> list[Measurement]:
    named = set(record.failed_measurements)
    return [m for m in record.measurements if m.outcome == Outcome.FAIL or m.name in named]


def overdue_instruments(record: RunRecord) -> list[str]:
    """Instruments whose calibration was overdue on the day of the run (flag or date)."""
    run_day = parse_utc(record.started_utc)
    out = []
    for inst in sorted(record.instruments, key=lambda i: i.role):
        due: date | None = None
        if inst.calibration_due:
            try:
                due = date.fromisoformat(inst.calibration_due[:10])
            except ValueError:
                due = None
        late = inst.calibration_overdue or (
            due is not None and run_day is not None and due < run_day.date()
        )
        if late:
            out.append(f"{inst.role} ({inst.model or 'model?'} s/n {inst.serial or '?'}, "
                       f"due {inst.calibration_due or 'unknown'})")
    return out


def header(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    verdict = inputs.verdict
    story: list[Flowable] = [Paragraph("Calibration certificate - MEMS gyroscope", H1)]
    serial = rec.dut.serial if rec else inputs.folder.name
    banner = Table(
        [[Paragraph(escape(verdict), verdict_style(verdict))]],
        colWidths=[CONTENT_WIDTH],
        rowHeights=[14 * mm],
    )
    banner.setStyle(TableStyle([
        ("BACKGROUND", (0, 0), (-1, -1), VERDICT_COLOURS.get(verdict, colors.grey)),
        ("VALIGN", (0, 0), (-1, -1), "MIDDLE"),
    ]))
    story += [Spacer(1, 2 * mm), banner, Spacer(1, 1.5 * mm)]
    story += safe_state_box(rec, CONTENT_WIDTH)
    if verdict == "FAIL" and rec is not None:
        names = [
            f"{m.name}{' @ ' + m.condition if m.condition else ''} = "
            f"{with_units(m.value, m.units)} (limits {fmt(m.low)} .. {fmt(m.high)})"
            for m in failing(rec)
        ] or ["(the record names no failing measurement)"]
        story.append(Paragraph("<b>Failing measurements:</b> " + escape("; ".join(names)),
                               WARNING))
    elif verdict != "PASS":
        story.append(Paragraph(f"<b>Reason:</b> {escape(inputs.reason or 'not recorded')}",
                               WARNING))
        if rec is not None and failing(rec):
            story.append(Paragraph("<b>Measurements already outside their limits:</b> " + escape(
                "; ".join(f"{m.name}{' @ ' + m.condition if m.condition else ''} = "
                          f"{with_units(m.value, m.units)}" for m in failing(rec))), WARNING))
    if rec is not None:
        for late in overdue_instruments(rec):
            story.append(Paragraph(
                f"INSTRUMENT CALIBRATION OVERDUE on the day of this run: {escape(late)}", WARNING))
    rows = _identity_rows(inputs, serial)
    style = grid_style(header_rows=0)
    style.add("BACKGROUND", (0, 0), (0, -1), HEADER_GREY)
    table = fitted_table([[_p(k), _p(v)] for k, v in rows], CONTENT_WIDTH, style)
    story += [Spacer(1, 2 * mm), table]
    if rec is not None:
        story.append(Spacer(1, 1.5 * mm))
        story.append(Paragraph(escape(summary_text(rec)), BODY))
    return story


def summary_text(rec: RunRecord) -> str:
    """One paragraph for page one: what was tested, how, and how it came out."""
    temps = sorted({c.temperature_c for c in rec.conditions})
    volts = sorted({c.supply_v for c in rec.conditions})
    proc = rec.procedure.name or rec.procedure.path
    where = (f" at {len(rec.conditions)} conditions ("
             + "/".join(fmt(t) for t in temps) + " C, " + "/".join(fmt(v) for v in volts)
             + " V)" if rec.conditions
             else cert_ramp.summary(rec) or ", no condition recorded")
    how = (f"Tested with procedure {proc}" + (f" v{rec.procedure.version}"
                                               if rec.procedure.version else "") + where)
    counts = {o: sum(m.outcome == o for m in rec.measurements) for o in Outcome}
    out = (f"{len(rec.measurements)} measurements: {counts[Outcome.FAIL]} failed, "
           f"{counts[Outcome.MARGINAL]} marginal, {counts[Outcome.NOT_MEASURED]} not measured")
    cal = rec.calibration
    three_axis = cert_three_axis.summary(rec)
    if three_axis is not None:
        cal_text = three_axis
    elif cal is None:
        cal_text = "No calibration was written to the part"
    elif (why := record_keys.not_programmed(rec.analysis)) is not None:
        cal_text = f"Calibration fitted but not written to the part ({why})"
    else:
        rb = {True: "read-back PASSED", False: "read-back FAILED",
              None: "read-back not recorded"}[cal.readback_ok]
        cal_text = (f"Calibration written: bias {fmt(cal.bias_dps.value)} +/- "
                    f"{fmt(cal.bias_dps.uncertainty_k2, 2)} deg/s, scale {fmt(cal.scale.value, 6)}"
                    f" +/- {fmt(cal.scale.uncertainty_k2, 2)} (k = 2); {rb}")
    v = rec.verification
    if v is not None and v.max_error_pct is not None:
        cal_text += f"; verification largest error {fmt(v.max_error_pct, 3)} % of rate"
    return f"{how}. {out}. {cal_text}."


def _identity_rows(inputs: CertificateInputs, serial: str) -> list[tuple[str, str]]:
    rec = inputs.record
    if rec is None:
        return [("Run folder", str(inputs.folder)), ("Part serial", f"unknown ({serial})")]
    st = rec.station
    reg = rec.dut.part_serial_register
    part = serial if reg in (None, serial) else f"{serial} (part register reads {reg}: MISMATCH)"
    return [
        ("Certificate number", rec.certificate_number or "not issued (no number recorded)"),
        ("Product", rec.dut.product or rec.product.name or rec.product.path),
        ("Part serial", part + (f", socket {rec.dut.socket}" if rec.dut.socket else "")),
        ("Run id", rec.run_id),
        ("Started", f"{utc_text(rec.started_utc)}  |  station local: "
                    f"{local_time_text(rec.started_utc, rec.station_local_tz)}"),
        ("Finished", utc_text(rec.finished_utc)),
        ("Station", " ".join(str(st[k]) for k in ("id", "name", "location") if st.get(k))
         or "not recorded"),
        ("Operator", rec.operator or "not recorded"),
        ("Software version", rec.software_version or "not recorded"),
        ("Bench", "SIMULATED bench (no real instruments)" if rec.simulated else "real instruments"),
        *_simulated_part_row(rec),
    ]


def _simulated_part_row(rec: RunRecord) -> list[tuple[str, str]]:
    """A model's twin (a simulated part declared to carry a model's effects): which."""
    if not rec.simulated or rec.simulated_part_effects is None:
        return []
    ids = ", ".join(rec.simulated_part_effects) or "none (bias and scale only)"
    return [("Simulated part", bounded(f"a model's twin; effects it carries: {ids}", 600))]


def traceability(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    story: list[Flowable] = [Paragraph("Traceability", H2)]
    rows = [[_p("Item"), _p("File"), _p("Version"), _p("SHA-256")]]
    if rec is not None:
        refs = [("Procedure", rec.procedure), ("Product", rec.product)]
        if rec.station_config is not None:
            refs.append(("Station config", rec.station_config))
        for label, ref in refs:
            # the version column is narrow: a long version would outgrow a page
            rows.append([_p(label), _p(ref.name or ref.path),
                         _p(bounded(ref.version or "-", 120)),
                         _p(ref.sha256, CELL_MONO)])
    raw_note = inputs.raw_sha256 or "file missing"
    rows.append([_p("Raw data"), _p(inputs.raw_path.name), _p("-"), _p(raw_note, CELL_MONO)])
    story.append(fitted_table(rows, CONTENT_WIDTH, grid_style(), repeatRows=1))
    story.append(Spacer(1, 2 * mm))
    irows = [[_p(h) for h in ("Role", "Instrument", "Serial", "Firmware", "Address",
                               "Calibration due")]]
    overdue_rows = []
    if rec is not None:
        late = {s.split(" ")[0] for s in overdue_instruments(rec)}
        for i, inst in enumerate(sorted(rec.instruments, key=lambda x: x.role), start=1):
            due = inst.calibration_due or "not recorded"
            if inst.role in late:
                due += " OVERDUE"
                overdue_rows.append(i)
            irows.append([_p(inst.role), _p(f"{inst.manufacturer} {inst.model}".strip() or "-"),
                          _p(inst.serial or "-"), _p(inst.firmware or "-"),
                          _p(inst.address or "-"), _p(due)])
    if len(irows) == 1:
        irows.append([_p("no instruments recorded")] + [_p("")] * 5)
    style = grid_style()
    for r in overdue_rows:
        style.add("BACKGROUND", (0, r), (-1, r), FAIL_ROW)
    story.append(fitted_table(irows, CONTENT_WIDTH, style, repeatRows=1))
    return story


def conditions(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    story: list[Flowable] = [Paragraph("Test conditions", H2)]
    ramp = cert_ramp.ramp_conditions(rec) if rec is not None else []
    if rec is None or not rec.conditions:
        return story + (ramp or [Paragraph("No conditions recorded.", NOTE)])
    heads = ["Condition", "Chamber set (C)", "Die temp (C)", "Supply set (V)",
             "Supply measured (V)", "Supply current (A)", "Time to stability (s)", "Stable"]
    rows: list[list[str | Paragraph]] = [[_p(h) for h in heads]]
    for c in rec.conditions:
        measured = c.supply_measured_v
        # numbers as plain strings: never broken inside (table_fit sizes their columns)
        rows.append([_p(c.name), fmt(c.temperature_c), fmt(c.die_temperature_c),
                     fmt(c.supply_v),
                     fmt(measured) if measured is not None else "-",
                     fmt(c.supply_current_a), fmt(c.time_to_stability_s),
                     fmt(c.stable) if c.stable is not None else "-"])
    t = fitted_table(rows, CONTENT_WIDTH, grid_style(), repeatRows=1)
    crit = record_keys.stability(rec.analysis)
    story.append(t)
    if crit:
        texts: list[tuple[str, str]] = []
        for name, crit_c in crit.items():
            parts = []
            if crit_c.band_c is not None:
                parts.append(f"peak-to-peak below {fmt(crit_c.band_c)} C")
            if crit_c.max_rate_c_per_min is not None:
                parts.append(f"|slope| below {fmt(crit_c.max_rate_c_per_min)} C/min")
            if crit_c.window_s is not None and parts:
                parts[-1] += f" over the last {fmt(crit_c.window_s)} s"
            if crit_c.tolerance_c is not None:
                parts.append(f"within {fmt(crit_c.tolerance_c)} C of the setpoint")
            texts.append((name, ' and '.join(parts) or 'criterion not stated'))
        by_text: dict[str, list[str]] = {}
        for name, text in texts:
            by_text.setdefault(text, []).append(name)
        joined = "; ".join(f"{', '.join(names)}: {text}" for text, names in by_text.items())
        story.append(Paragraph("Stability criterion (judged on the part's own temperature "
                               "sensor): " + escape(joined), NOTE))
    return story + ramp


def margin(m: Measurement) -> tuple[float | None, str]:
    """Distance to the nearest limit (positive inside) and that as % of the half tolerance."""
    if m.value is None:
        return None, "-"
    dists = [d for d in (None if m.low is None else m.value - m.low,
                         None if m.high is None else m.high - m.value) if d is not None]
    if not dists:
        return None, "no limits"
    d = min(dists)
    if m.low is not None and m.high is not None and m.high > m.low:
        return d, margin_pct(d / ((m.high - m.low) / 2) * 100)
    return d, ""


MARGIN_PCT_SHOWN = 999  # beyond this many % of the half tolerance the figure says nothing


def margin_pct(pct: float) -> str:
    """The margin as % of half the tolerance; a no-break space keeps the per cent with its
    number when the cell wraps, and a part far outside shows as beyond +/-999 %."""
    if pct > MARGIN_PCT_SHOWN:
        return f">{MARGIN_PCT_SHOWN}\u00a0%"
    if pct < -MARGIN_PCT_SHOWN:
        return f"<-{MARGIN_PCT_SHOWN}\u00a0%"
    return f"{pct:.0f}\u00a0%"


def outcome_text(m: Measurement) -> str:
    """The outcome as the table shows it: a measurement without limits is recorded, not
    passed (the record's outcome stays PASS)."""
    if m.outcome == Outcome.PASS and m.low is None and m.high is None:
        return "recorded (no limit)"
    return m.outcome.value.replace("_", " ")


def results(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    story: list[Flowable] = [Paragraph("Results", H2)]
    if rec is None or not rec.measurements:
        return story + [Paragraph("No measurements recorded.", NOTE)]
    heads = ["Measurement", "Condition", "Value", "U (k=2)", "Units", "Low", "High",
             "Margin", "Outcome"]
    rows: list[list[str | Paragraph]] = [[_p(h) for h in heads]]
    style = grid_style()
    # nine columns: a narrower padding leaves the longest values of every column their room
    style.add("LEFTPADDING", (0, 0), (-1, -1), 2)
    style.add("RIGHTPADDING", (0, 0), (-1, -1), 2)
    for i, m in enumerate(rec.measurements, start=1):
        d, pct = margin(m)
        # Numbers as plain strings (never broken; table_fit gives each column its widest);
        # names, units, the margin's "value %" and the outcome as paragraphs, which may wrap
        # at a space ("NOT / MEASURED"), so that the numbers keep their room.
        words = CELL_BOLD if m.outcome == Outcome.FAIL else CELL
        rows.append([_p(m.name), _p(m.condition or "-"), fmt(m.value),
                     fmt(m.uncertainty_k2, 3), _p(unit_label(m.units)), fmt(m.low), fmt(m.high),
                     _p(f"{fmt(d, 3)} {pct}".strip() if d is not None else pct, words),
                     _p(outcome_text(m), words)])
        if m.outcome == Outcome.FAIL:
            style.add("BACKGROUND", (0, i), (-1, i), FAIL_ROW)
            style.add("FONT", (0, i), (-1, i), FONT_BOLD, 7.5)
        elif m.outcome == Outcome.MARGINAL:
            style.add("BACKGROUND", (0, i), (-1, i), MARGINAL_AMBER)
        elif m.outcome == Outcome.NOT_MEASURED:
            style.add("TEXTCOLOR", (0, i), (-1, i), colors.grey)
    t = fitted_table(rows, CONTENT_WIDTH, style, repeatRows=1)
    n_fail = sum(m.outcome == Outcome.FAIL for m in rec.measurements)
    n_marg = sum(m.outcome == Outcome.MARGINAL for m in rec.measurements)
    story += [t, Paragraph(
        f"{len(rec.measurements)} measurements: {n_fail} failed (red), {n_marg} marginal "
        "(amber: inside the limits but within the marginal band). Margin = distance to the "
        "nearest limit in the measurement's units (negative = outside), and as % of half the "
        "tolerance.", NOTE)]
    return story


# (record key, label, units, key of the same coefficient in `calibration.readback`). The
# readback dict holds the part's register names (drivers.protocols.CalibrationRegisters,
# written by procedures/steps/program.py), which differ from the record's key for four of
# the six; both spellings are looked up so older or hand-made records also show.
_COEFFS = [
    ("bias_dps", "Bias", "deg/s", "bias_dps"),
    ("bias_temp_coeff_dps_per_c", "Bias temperature coefficient", "deg/s/C",
     "bias_tc_dps_per_c"),
    ("bias_supply_coeff_dps_per_v", "Bias supply coefficient", "deg/s/V", "bias_vc_dps_per_v"),
    ("scale", "Scale (output/input)", "1", "scale"),
    ("scale_temp_coeff_per_c", "Scale temperature coefficient", "1/C", "scale_tc_per_c"),
    ("scale_supply_coeff_per_v", "Scale supply coefficient", "1/V", "scale_vc_per_v"),
]
# The terms beyond first order an order-2 or -3 fit adds to the calibration block (extra keys,
# procedures/steps/fit_order.py), each after its first-order term; shown when present.
_HIGHER_COEFFS = {
    "bias_temp_coeff_dps_per_c": [
        ("bias_temp_coeff2_dps_per_c2", "Bias temperature coefficient, 2nd order",
         "deg/s/C^2", "bias_tc2_dps_per_c2"),
        ("bias_temp_coeff3_dps_per_c3", "Bias temperature coefficient, 3rd order",
         "deg/s/C^3", "bias_tc3_dps_per_c3")],
    "scale_temp_coeff_per_c": [
        ("scale_temp_coeff2_per_c2", "Scale temperature coefficient, 2nd order", "1/C^2",
         "scale_tc2_per_c2"),
        ("scale_temp_coeff3_per_c3", "Scale temperature coefficient, 3rd order", "1/C^3",
         "scale_tc3_per_c3")],
}


def calibration_terms(cal: Calibration) -> list[tuple[str, str, str, str, Coefficient]]:
    """(key, label, units, register, coefficient) of every term written to the part: the
    six first-order ones and whichever higher-order ones the record holds."""
    out = []
    for key, label, units, register in _COEFFS:
        out.append((key, label, units, register, getattr(cal, key)))
        for hkey, hlabel, hunits, hregister in _HIGHER_COEFFS.get(key, []):
            coeff = getattr(cal, hkey)
            if coeff is not None:  # None: a first-order fit, not a programmed term
                out.append((hkey, hlabel, hunits, hregister, coeff))
    return out


def readback_value(readback: dict[str, float], key: str, register: str) -> float | None:
    """The read-back value of one coefficient, under its register name or its record key."""
    for k in (register, key):
        if k in readback:
            return readback[k]
    return None


def calibration(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    cal = rec.calibration if rec else None
    why = record_keys.not_programmed(rec.analysis) if rec else None
    if cal is not None and why is not None:
        story: list[Flowable] = [
            Paragraph("Calibration fitted (not written to the part)", H2),
            Paragraph(f"Not written to the part: {escape(why)}. The coefficients below "
                      "are what the fit found; the part keeps the calibration it had.", NOTE)]
    else:
        story = [Paragraph("Calibration written to the part", H2)]
    if cal is None:
        return story + [Paragraph("No calibration was written to this part.", NOTE)]
    readback = cal.readback or {}
    rows: list[list[str | Paragraph]] = [[_p(h) for h in (
        "Coefficient", "Key", "Value", "U (k=2)", "Units", "Read back")]]
    for key, label, units, register, c in calibration_terms(cal):
        rows.append([_p(label), _p(key, CELL_MONO), fmt(c.value, 7),
                     fmt(c.uncertainty_k2, 3), _p(unit_label(units)),
                     fmt(readback_value(readback, key, register), 7)])
    story.append(fitted_table(rows, CONTENT_WIDTH, grid_style(), repeatRows=1))
    bias, scale = cal.bias_dps.value, cal.scale.value
    rb = {True: "PASSED (registers read back equal to the values written)",
          False: "FAILED (registers read back differ from the values written)",
          None: "not recorded"}[cal.readback_ok] if why is None else "none (not written)"
    story.append(Paragraph(
        f"Reference conditions {fmt(cal.reference_temperature_c)} C, "
        f"{fmt(cal.reference_supply_v)} V; coefficients act on dT = die temperature - "
        f"{fmt(cal.reference_temperature_c)} C and dV = supply - {fmt(cal.reference_supply_v)} V. "
        f"<b>Sign conventions:</b> the bias is what the part outputs at zero rate; the bias "
        f"correction is minus the bias ({fmt(-bias)} deg/s here). The scale is output divided by "
        f"input; the scale correction is input divided by output "
        f"({fmt(1 / scale if scale else None)} "
        f"here). Corrected rate = (output + bias correction) x scale correction. "
        f"Uncertainties are expanded, k = 2 (about 95 %). <b>Read-back check:</b> {rb}.", BODY))
    if cal.interaction_check:
        items = ", ".join(f"{k} = {fmt(v)}" for k, v in sorted(cal.interaction_check.items()))
        story.append(Paragraph(f"Interaction check (spare degree of freedom of the 2 x 2 "
                               f"conditions): {escape(items)}", NOTE))
    story += verification(rec)
    return [KeepTogether(story[:3])] + story[3:]


def verification(rec: RunRecord | None) -> list[Flowable]:
    story: list[Flowable] = [Paragraph("Verification after correction", H2)]
    rows_in = record_keys.verification_residuals(rec.verification if rec else None)
    if not rows_in:
        return story + [Paragraph("No verification residuals recorded.", NOTE)]
    rows: list[list[str | Paragraph]] = [[_p(h) for h in (
        "Condition", "Input rate (deg/s)", "Residual (deg/s)", "Residual (%)")]]
    for r in rows_in:
        rows.append([_p(r.condition or "-"), fmt(r.rate_in_dps),
                     fmt(r.error_dps, 3), fmt(r.error_pct, 3)])
    t = fitted_table(rows, CONTENT_WIDTH, grid_style(), repeatRows=1)
    story.append(t)
    v = rec.verification if rec else None
    if v is not None and v.max_error_pct is not None:
        story.append(Paragraph(f"Largest verification error {fmt(v.max_error_pct, 3)} % "
                               f"of the input rate.", NOTE))
    return story


def approval_date(entry: dict[str, Any]) -> str:
    """An approval's time as the box shows it (UTC, to the minute)."""
    t = parse_utc(str(entry.get("time_utc", "")))
    return f"{t:%Y-%m-%d %H:%M} UTC" if t else str(entry.get("time_utc") or "not recorded")


def sign_off(approvals: Sequence[dict[str, Any]] = ()) -> Table:
    """The quality engineer's review box: one row per recorded approval (name, role and
    remark; date; that it is signed, and in which PDF signature field), or an empty row to
    be filled in by hand when the run has not been approved."""
    heads = ["Reviewed by (quality)", "Date", "Signature"]
    rows: list[list[str | Paragraph]] = [[_p(h) for h in heads]]
    for n, entry in enumerate(approvals, start=1):
        who = f"{entry.get('by', '?')} ({entry.get('role', 'quality')})"
        remark = str(entry.get("remark") or "").strip()
        rows.append([_p(who + (f"; remark: {remark}" if remark else "")),
                     approval_date(entry),
                     _p(f"signed digitally (PDF signature Approval-{n}, station key)")])
    if len(rows) == 1:
        rows.append([_p(""), "", _p("")])
    style = grid_style()
    table = fitted_table(rows, CONTENT_WIDTH, style)
    if not approvals:  # room to sign by hand
        table = Table(rows, colWidths=table._colWidths, rowHeights=[None, 10 * mm])
        table.setStyle(style)
    return table


def generated_note(inputs: CertificateInputs, when: datetime) -> Paragraph:
    return Paragraph(
        f"Rendered from {escape(inputs.folder.name)}/record.json and {escape(inputs.raw_path.name)}"
        f"; document date = run finish time {when:%Y-%m-%d %H:%M:%S} UTC. Re-render with "
        "<font face='DejaVuSansMono'>station report RUN_FOLDER</font>.", NOTE)
