"""The calibration certificate: `certificate.pdf` in every run folder, for every verdict.

`render_certificate(run_folder)` is called by the engine at the end of every run and by
`station report RUN_FOLDER`. It reads only `record.json` and the raw data file, so the same
folder always gives the same bytes (reportlab invariant mode, document date = the run's
finish time). A folder with a missing or broken record or data file still gets a
certificate, with verdict ERROR and the problem stated on page one.

Page one: verdict banner, failing measurements or the reason, overdue-instrument warning,
identity (certificate number, product, serial, times UTC and station local, station,
operator, software). Then traceability, decision rule / reference standards / ambient
(reports/cert_standards.py), conditions, results, calibration with uncertainties and
verification, and the plots of the steps the procedure planned (reports/cert_figures.py,
reports/cert_plots.py, reports/cert_ramp_chart.py; the analysis sections read are the
typed models of procedures/runtime/results.py).

This module renders only; station/certify.py numbers, signs (PAdES) and seals the folder.
With `unverified` set every page is marked UNVERIFIED (a folder that failed verification).
"""

from __future__ import annotations

import logging
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from reportlab.platypus import Flowable, KeepTogether, Spacer

from procedures.runtime.record import CERTIFICATE_FILE
from reports import (
    cert_figures,
    cert_remeasured,
    cert_sections,
    cert_standards,
    cert_temperature_fit,
    cert_three_axis,
)
from reports.cert_inputs import CertificateInputs, load_inputs
from reports.pdfdoc import PageFurniture, build_pdf, parse_utc, write_atomic
from reports.styles import bounded

log = logging.getLogger(__name__)

_EPOCH = datetime(2000, 1, 1, tzinfo=UTC)


def document_time(inputs: CertificateInputs) -> datetime:
    """The run's finish (or start) time; a fixed epoch when the record gives none."""
    rec = inputs.record
    if rec is not None:
        for text in (rec.finished_utc, rec.started_utc):
            t = parse_utc(text)
            if t is not None:
                return t
    return _EPOCH


def build_story(inputs: CertificateInputs) -> list[Flowable]:
    when = document_time(inputs)
    story: list[Flowable] = []
    story += cert_sections.header(inputs)
    story += cert_sections.traceability(inputs)
    story += cert_standards.standards(inputs)
    story += cert_sections.conditions(inputs)
    story += cert_sections.results(inputs)
    story += cert_remeasured.remeasured(inputs)
    three_axis = cert_three_axis.three_axis(inputs)
    story += three_axis or cert_sections.calibration(inputs)
    story += cert_temperature_fit.temperature_fit(inputs)
    if inputs.record is not None:
        story += cert_figures.all_plots(inputs)
    story += [Spacer(1, 8), KeepTogether([cert_sections.sign_off(inputs.approvals),
                                          Spacer(1, 4),
                                          cert_sections.generated_note(inputs, when)])]
    return story


def certificate_bytes(run_folder: Path, *, unverified: str = "",
                      approvals: list[dict[str, Any]] | None = None) -> bytes:
    """The certificate of a run folder as PDF bytes (nothing written). `unverified`: why
    the folder failed verification; marks every page UNVERIFIED with that reason.
    `approvals`: the quality approvals to show in the sign-off box (default: those in the
    folder's approvals.json)."""
    inputs = load_inputs(run_folder, approvals)
    rec = inputs.record
    serial = bounded(rec.dut.serial if rec else "unknown serial", 64)
    run_id = bounded(rec.run_id if rec else run_folder.name, 80)
    furniture = PageFurniture(
        title="Calibration certificate",
        identity=f"{serial}  |  {run_id}  |  {inputs.verdict}",
        simulated=bool(rec.simulated) if rec else False,
        document_time=document_time(inputs),
        author=bounded(rec.operator, 120) if rec else "",
        subject=f"{inputs.verdict} {serial}",
        unverified=bounded(unverified, 120),
    )
    return build_pdf(build_story(inputs), furniture)


def render_certificate(run_folder: Path) -> Path:
    """Write `certificate.pdf` into the run folder and return its path; never raises on bad data.

    Raises only when the folder itself cannot be written (permissions, disk full).
    """
    run_folder = Path(run_folder)
    start = time.perf_counter()
    data = certificate_bytes(run_folder)
    path = write_atomic(run_folder / CERTIFICATE_FILE, data)
    log.info("certificate %s written in %.2f s", path, time.perf_counter() - start)
    return path
