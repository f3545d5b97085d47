"""Which plots a certificate shows: those of the steps its procedure planned.

A section whose step is not in the run's procedure (`record.analysis.plan.steps`, the step
types the engine planned) is left out, and one line names what the procedure does not
include; a section whose step was planned but left nothing keeps its "Not drawn"
explanation (a real gap). A record without the planned steps (written before the engine
recorded them) shows the four classic sections as it always did, and the ramp's when the
record holds a ramp section. The stop method's shows whenever the record holds stop-method
records of a ramp (`analysis.ramp_stop`), whatever the plan.
"""

from __future__ import annotations

from collections.abc import Callable

from reportlab.platypus import Flowable, KeepTogether, Paragraph

from procedures.runtime.record import RunRecord, three_axis_block
from reports import cert_plots, cert_ramp_chart
from reports.cert_inputs import CertificateInputs
from reports.styles import NOTE, escape

Section = Callable[[CertificateInputs], list[Flowable]]

# each section, what it is called, and the step types whose data it draws
SECTIONS: tuple[tuple[Section, str, frozenset[str]], ...] = (
    (cert_plots.stop_method, "stop method", frozenset({"stop_method", "manual_stop"})),
    (cert_plots.rate_table, "rate table", frozenset({"rate_table"})),
    (cert_plots.allan, "Allan deviation", frozenset({"bias"})),
    (cert_plots.stabilisation, "thermal stabilisation",
     frozenset({"thermal", "thermal_judged_after"})),
    (cert_ramp_chart.ramp, "ramp calibration", frozenset({"ramp_calibration"})),
)


def planned_steps(rec: RunRecord) -> set[str] | None:
    """The step types the run's procedure planned; None when the record does not say."""
    plan = rec.analysis.plan
    return set(plan.steps) if plan is not None and plan.steps else None


def _wanted(rec: RunRecord, planned: set[str] | None, name: str, steps: frozenset[str]
            ) -> bool:
    if name == "stop method" and rec.analysis.ramp_stop is not None:
        return True  # the ramp carried stop-method records
    if planned is not None:
        return bool(planned & steps)
    if name == "ramp calibration":  # older records: the ramp's only when it left a section
        return rec.analysis.ramp is not None
    return True


def _heading_with_first(items: list[Flowable]) -> list[Flowable]:
    """Never leave a section heading alone at the foot of a page."""
    return [KeepTogether(items[:3])] + items[3:] if len(items) > 1 else items


def all_plots(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    if rec is None:
        return []
    sections = SECTIONS
    if three_axis_block(rec) is not None:  # a cube has no stop, rate-table or noise record
        sections = tuple(s for s in SECTIONS if s[0] is cert_plots.stabilisation)
    planned = planned_steps(rec)
    story: list[Flowable] = []
    left_out: list[str] = []
    for section, name, steps in sections:
        if _wanted(rec, planned, name, steps):
            story += _heading_with_first(section(inputs))
        elif name != "ramp calibration":
            left_out.append(name)
    if left_out:
        proc = rec.procedure.name or rec.procedure.path
        story.append(Paragraph(escape(
            f"Procedure {proc} does not include: {', '.join(left_out)} (no plot for them)."),
            NOTE))
    return story
