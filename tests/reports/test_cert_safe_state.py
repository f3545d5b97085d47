"""Page one of the certificate states a failed safe state (from the record's own report)."""

from __future__ import annotations

import re
from pathlib import Path

from procedures.runtime.record import read_record, write_record
from procedures.runtime.results import SafeStateResults
from reports.certificate import render_certificate
from tests.reports.conftest import pdf_text


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def _report(table_safe: bool) -> dict[str, object]:
    return {
        "all_safe": table_safe,
        "instruments": {
            "rate_table": {
                "name": "rate_table", "safe": table_safe, "attempts": 9,
                "detail": "ConnectionLost: cannot connect to the rate table at 10.0.0.5:502",
            },
            "supply": {"name": "supply", "safe": True, "attempts": 1, "detail": "output off"},
        },
    }


def test_failed_safe_state_is_on_page_one(tmp_path: Path) -> None:
    from tests.reports.synth_run import Part, make_run

    folder, _ = make_run(tmp_path, Part(serial="SIM-SAF-1", verdict="ERROR"))
    rec = read_record(folder)
    rec.analysis.safe_state_report = SafeStateResults.model_validate(_report(table_safe=False))
    write_record(folder, rec)
    page1 = _flat(pdf_text(render_certificate(folder), page=1))
    assert "SAFE STATE FAILED" in page1
    assert "Rate table NOT SAFE after 9 attempt(s)" in page1 and "10.0.0.5:502" in page1
    assert "DC supply NOT SAFE" not in page1


def test_no_box_when_every_instrument_read_back_safe(tmp_path: Path) -> None:
    from tests.reports.synth_run import Part, make_run

    folder, _ = make_run(tmp_path, Part(serial="SIM-SAF-2", verdict="ERROR"))
    rec = read_record(folder)
    rec.analysis.safe_state_report = SafeStateResults.model_validate(_report(table_safe=True))
    write_record(folder, rec)
    assert "SAFE STATE FAILED" not in pdf_text(render_certificate(folder), page=1)
