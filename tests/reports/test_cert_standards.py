"""Decision rule, reference standards and ambient on the certificate; guard-banded judging."""

from __future__ import annotations

from pathlib import Path

from procedures.runtime.limits import Limit, Limits, judge
from procedures.runtime.record import Outcome, read_record
from station.certify import ensure_certificate_number
from station.station_file import load_settings
from tests.reports.conftest import pdf_text
from tests.reports.test_signing import station_file

LIMITS = Limits(residual_bias_dps=Limit(low=-1.0, high=1.0, units="deg/s"))


def test_guard_band_narrows_acceptance_by_the_expanded_uncertainty() -> None:
    def outcome(value: float, rule: str) -> Outcome:
        return judge("residual_bias_dps", value, LIMITS, uncertainty_k2=0.2,
                     decision_rule=rule).outcome

    assert outcome(0.9, "simple") is Outcome.PASS
    assert outcome(0.9, "guard_banded") is Outcome.FAIL  # within U of the limit
    assert outcome(-0.85, "guard_banded") is Outcome.FAIL
    assert outcome(0.7, "guard_banded") is Outcome.PASS
    assert judge("residual_bias_dps", 0.9, LIMITS, decision_rule="guard_banded").outcome \
        is Outcome.PASS  # no uncertainty stated: nothing to guard with


def test_certificate_states_rule_standards_and_ambient(fresh_run: Path, tmp_path: Path) -> None:
    from reports.certificate import render_certificate

    settings = load_settings(station_file(tmp_path / "station"))
    ensure_certificate_number(fresh_run, settings, "guard_banded")
    context = read_record(fresh_run).certificate_context
    assert context is not None and context.decision_rule == "guard_banded"
    rate_table = settings.settings.instruments.rate_table
    text = " ".join(pdf_text(render_certificate(fresh_run), layout=False).split())
    assert "Guard-banded acceptance" in text
    assert rate_table.calibration_certificate and rate_table.calibration_certificate in text
    ambient = settings.settings.ambient
    assert ambient is not None and f"{ambient.temperature_c:g} C" in text


def test_record_from_before_says_not_recorded(fresh_run: Path) -> None:
    from reports.certificate import render_certificate

    assert read_record(fresh_run).certificate_context is None
    text = " ".join(pdf_text(render_certificate(fresh_run), layout=False).split())
    assert "Decision rule: not recorded" in text and "Ambient conditions: not recorded" in text
