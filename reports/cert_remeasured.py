"""The certificate's note on judgements measured again (`record.analysis.remeasured`) and
on conditions measured again because their stability window, judged after the measurement,
failed (`record.analysis.measured_again`, the thermal step's `overlap_measurement`).

A part whose only failure was one judgement at a condition (the stop-vs-table consistency)
had that condition measured once more before its verdict; the certificate says so, with
both values, so the reader sees the first result was not dropped silently.
"""

from __future__ import annotations

from reportlab.platypus import Flowable, Paragraph

from procedures.runtime.results import RemeasuredFirst, RemeasuredSecond
from reports.cert_inputs import CertificateInputs
from reports.styles import NOTE, escape, fmt


def _value(entry: RemeasuredFirst | RemeasuredSecond | None) -> str:
    if entry is None:
        return "not measured"
    return f"{fmt(entry.value)} ({escape(entry.outcome or '-')})"


def remeasured(inputs: CertificateInputs) -> list[Flowable]:
    """One line per judgement measured again; nothing when there is none."""
    rec = inputs.record
    entries = rec.analysis.remeasured if rec is not None else []
    lines = [Paragraph(
        f"Measured again: {escape(e.measurement)} at "
        f"{escape(e.condition or '-')} failed alone at first "
        f"({_value(e.first)}); the condition was measured once more and the "
        f"second result is the one judged: {_value(e.second)}.", NOTE) for e in entries]
    again = rec.analysis.measured_again if rec is not None else []
    return lines + [Paragraph(
        f"Measured again: {escape(a.condition)}: {escape(a.why)}; the condition was measured "
        f"once more after a full stability window and the second result is the one judged "
        f"(the first attempt's {len(a.first)} measurement(s) are kept in the record).", NOTE)
        for a in again]
