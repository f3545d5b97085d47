"""Page one's safe-state box: shown, in red, when the station could not bring an instrument to
its safe state at the end of the run (read from the record's `safe_state_report`, written by
the station's own readback of each instrument)."""

from __future__ import annotations

from reportlab.lib import colors
from reportlab.lib.styles import ParagraphStyle
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, Paragraph, Spacer, Table, TableStyle

from procedures.runtime.record import RunRecord
from procedures.runtime.results import InstrumentSafeResults
from reports.styles import BODY, FAIL_RED, FAIL_ROW, FONT_BOLD, escape

TITLE = ParagraphStyle(
    "safe_title", parent=BODY, fontName=FONT_BOLD, textColor=colors.white, fontSize=12, leading=15
)
LINE = ParagraphStyle("safe_line", parent=BODY, fontName=FONT_BOLD, fontSize=9, leading=11)
LABELS = {"rate_table": "Rate table", "supply": "DC supply", "chamber": "Thermal chamber",
          "streams": "Part streams"}


def unsafe_instruments(rec: RunRecord) -> list[tuple[str, InstrumentSafeResults]]:
    """(name, its report) for every instrument the record says is not safe."""
    report = rec.analysis.safe_state_report
    if report is None:
        legacy = rec.analysis.safe_state or {}
        return [(k, InstrumentSafeResults(name=k, safe=False, detail=v))
                for k, v in legacy.items() if v != "safe"]
    return [(name, s) for name, s in report.instruments.items() if not s.safe]


def safe_state_box(rec: RunRecord | None, width: float) -> list[Flowable]:
    """The red 'SAFE STATE FAILED' box, or nothing when every instrument read back safe."""
    if rec is None:
        return []
    unsafe = unsafe_instruments(rec)
    if not unsafe:
        return []
    rows: list[list[Flowable]] = [[Paragraph(
        "SAFE STATE FAILED - the bench was NOT left safe: make it safe by hand before anyone "
        "touches it", TITLE)]]
    for name, s in unsafe:
        tries = f" after {s.attempts} attempt(s)" if s.attempts else ""
        rows.append([Paragraph(
            f"{escape(LABELS.get(name, name))} NOT SAFE{tries}: {escape(s.detail or '?')}",
            LINE)])
    table = Table(rows, colWidths=[width])
    table.setStyle(TableStyle([
        ("BACKGROUND", (0, 0), (-1, 0), FAIL_RED),
        ("BACKGROUND", (0, 1), (-1, -1), FAIL_ROW),
        ("BOX", (0, 0), (-1, -1), 1.5, FAIL_RED),
        ("TOPPADDING", (0, 0), (-1, -1), 3),
        ("BOTTOMPADDING", (0, 0), (-1, -1), 3),
    ]))
    return [table, Spacer(1, 1.5 * mm)]
