"""The certificate's note on judgements measured again (`record.analysis.remeasured`).

A part whose only failure was one judgement at a condition (the stop-vs-table consistency)
had that condition measured once more before its verdict; the certificate says so, with
both values, so the reader sees the first result was not dropped silently.
"""

from __future__ import annotations

from typing import Any

from reportlab.platypus import Flowable, Paragraph

from reports.cert_inputs import CertificateInputs
from reports.styles import NOTE, escape, fmt


def _value(entry: Any) -> str:
    if not isinstance(entry, dict):
        return "not measured"
    value = entry.get("value")
    number = fmt(float(value)) if isinstance(value, int | float) else "-"
    return f"{number} ({escape(str(entry.get('outcome', '-')))})"


def remeasured(inputs: CertificateInputs) -> list[Flowable]:
    """One line per judgement measured again; nothing when there is none."""
    rec = inputs.record
    entries = rec.analysis.get("remeasured") if rec is not None else None
    if not isinstance(entries, list):
        return []
    lines = []
    for e in entries:
        if not isinstance(e, dict):
            continue
        lines.append(Paragraph(
            f"Measured again: {escape(str(e.get('measurement', '-')))} at "
            f"{escape(str(e.get('condition', '-')))} failed alone at first "
            f"({_value(e.get('first'))}); the condition was measured once more and the "
            f"second result is the one judged: {_value(e.get('second'))}.", NOTE))
    return lines
