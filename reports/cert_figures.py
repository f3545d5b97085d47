"""Which plots a certificate shows: those of the steps its procedure planned.

A section whose step is not in the run's procedure (`record.analysis.plan.steps`, the step
types the engine planned) is left out, and one line names what the procedure does not
include; a section whose step was planned but left nothing keeps its "Not drawn"
explanation (a real gap). A section whose data another step recorded is drawn whatever the
plan: the stop method's when the record holds a ramp's stop-method records
(`analysis.ramp_stop`), the Allan deviation's when it holds a noise record (`analysis.allan`,
e.g. the ramp's static dwell). A record without the planned steps (written before the engine
recorded them) shows the four classic sections as it always did, and the ramp's when the
record holds a ramp section.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from reportlab.platypus import Flowable, KeepTogether, Paragraph

from procedures.runtime.record import RunRecord, three_axis_block
from procedures.runtime.results import Analysis
from reports import cert_plots, cert_ramp_chart
from reports.cert_inputs import CertificateInputs
from reports.styles import NOTE, escape

Section = Callable[[CertificateInputs], list[Flowable]]


class Figure(NamedTuple):
    """A plot section: how it is drawn, what it is called, the step types whose data it
    draws, whether the record holds its data whatever step wrote it, and whether a record
    without a plan shows it only when it holds that data."""

    draw: Section
    name: str
    steps: frozenset[str]
    holds: Callable[[Analysis], bool] = lambda a: False
    only_when_held: bool = False


SECTIONS: tuple[Figure, ...] = (
    Figure(cert_plots.stop_method, "stop method", frozenset({"stop_method", "manual_stop"}),
           lambda a: a.ramp_stop is not None),
    Figure(cert_plots.rate_table, "rate table", frozenset({"rate_table"})),
    Figure(cert_plots.allan, "Allan deviation", frozenset({"bias"}),
           lambda a: a.allan is not None),
    Figure(cert_plots.stabilisation, "thermal stabilisation",
           frozenset({"thermal", "thermal_judged_after"})),
    Figure(cert_ramp_chart.ramp, "ramp calibration", frozenset({"ramp_calibration"}),
           lambda a: a.ramp is not None, only_when_held=True),
)


def planned_steps(rec: RunRecord) -> set[str] | None:
    """The step types the run's procedure planned; None when the record does not say."""
    plan = rec.analysis.plan
    return set(plan.steps) if plan is not None and plan.steps else None


def _wanted(rec: RunRecord, planned: set[str] | None, fig: Figure) -> bool:
    if fig.holds(rec.analysis):
        return True
    if planned is not None:
        return bool(planned & fig.steps)
    return not fig.only_when_held


def _heading_with_first(items: list[Flowable]) -> list[Flowable]:
    """Never leave a section heading alone at the foot of a page."""
    return [KeepTogether(items[:3])] + items[3:] if len(items) > 1 else items


def all_plots(inputs: CertificateInputs) -> list[Flowable]:
    rec = inputs.record
    if rec is None:
        return []
    sections = SECTIONS
    if three_axis_block(rec) is not None:  # a cube has no stop, rate-table or noise record
        sections = tuple(s for s in SECTIONS if s.draw is cert_plots.stabilisation)
    planned = planned_steps(rec)
    story: list[Flowable] = []
    left_out: list[str] = []
    for fig in sections:
        if _wanted(rec, planned, fig):
            story += _heading_with_first(fig.draw(inputs))
        elif not fig.only_when_held:
            left_out.append(fig.name)
    if left_out:
        proc = rec.procedure.name or rec.procedure.path
        story.append(Paragraph(escape(
            f"Procedure {proc} has no step of its own for: {', '.join(left_out)} "
            "(no plot for them)."),
            NOTE))
    return story
