"""Certificate section: the decision rule, the reference standards and the ambient conditions.

Read from the record's `certificate_context` (written when the run ended, from station.yaml
and the product file); a record from before it says "not recorded" for each.
"""

from __future__ import annotations

from reportlab.lib.units import mm
from reportlab.platypus import Flowable, Paragraph, Spacer

from procedures.runtime.record import CertificateContext
from reports.cert_inputs import CertificateInputs
from reports.styles import BODY, CELL, H2, escape, fmt, grid_style
from reports.table_fit import fitted_table

CONTENT_WIDTH = 182 * mm
NOT_RECORDED = "not recorded"

RULES = {
    "simple": "Simple acceptance: a measurement inside its limits passes; the expanded "
              "uncertainty (k = 2) is stated beside each result but not applied.",
    "guard_banded": "Guard-banded acceptance: a measurement passes only inside its limits "
                    "narrowed on each side by its expanded uncertainty U (k = 2); a value "
                    "within U of a limit fails.",
}
ROLES = {"rate_table": "Rate table (encoder, table rate)", "chamber": "Chamber (temperature)",
         "supply": "Supply (voltage)", "fixture": "Fixture (stop angle)"}


def decision_rule_text(context: CertificateContext | None) -> str:
    if context is None or not context.decision_rule:
        return f"Decision rule: {NOT_RECORDED} (a record from before decision rules were kept)."
    return "Decision rule: " + RULES.get(context.decision_rule, context.decision_rule)


def ambient_text(context: CertificateContext | None) -> str:
    if context is None or context.ambient_temperature_c is None:
        return f"Ambient conditions: {NOT_RECORDED}."
    text = f"Ambient conditions: {fmt(context.ambient_temperature_c, 3)} C"
    if context.ambient_humidity_pct is not None:
        text += f", {fmt(context.ambient_humidity_pct, 3)} % relative humidity"
    return text + (f" (from the {context.ambient_source})." if context.ambient_source else ".")


def _rows(context: CertificateContext | None) -> list[list[Paragraph]]:
    head = [Paragraph(h, CELL) for h in ("Reference standard", "Calibration certificate",
                                         "Reference uncertainty", "Calibration due")]
    rows = [head]
    for std in (context.reference_standards if context else []):
        rows.append([Paragraph(escape(c), CELL) for c in (
            ROLES.get(std.role, std.role), std.calibration_certificate or NOT_RECORDED,
            std.reference_uncertainty or NOT_RECORDED, std.calibration_due or NOT_RECORDED)])
    if len(rows) == 1:
        rows.append([Paragraph(NOT_RECORDED, CELL)] + [Paragraph("", CELL)] * 3)
    return rows


def standards(inputs: CertificateInputs) -> list[Flowable]:
    """The section; empty when there is no record at all (the ERROR page says why)."""
    rec = inputs.record
    if rec is None:
        return []
    context = rec.certificate_context
    table = fitted_table(_rows(context), CONTENT_WIDTH, grid_style(), repeatRows=1)
    return [Paragraph("Decision rule, reference standards and ambient conditions", H2),
            Paragraph(escape(decision_rule_text(context)), BODY), Spacer(1, 1.5 * mm),
            table, Spacer(1, 1.5 * mm), Paragraph(escape(ambient_text(context)), BODY)]
