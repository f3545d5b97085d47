"""Certificates whose numbers never run together (issue 26, finding 4; finding 13).

A part at every limit's edge of the shipped product (on it, just inside, just outside), with
the longest values (-0.000123456789, long negative numbers, large uncertainties), a
third-order calibration and the longest condition names the procedures make: in
`pdftotext -layout` every value and every uncertainty is its own token, the value directly
followed by its uncertainty, and each condition name is whole. Before the tables sized their
columns to their content, a value and its U came out as one token (`-0.00177125.56e-05`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from procedures.runtime.conditions import Condition
from procedures.runtime.record import (
    Calibration,
    ConditionRecord,
    Measurement,
    Outcome,
    write_record,
)
from procedures.runtime.results import TemperatureFitResults, Verification
from reports.certificate import render_certificate
from reports.styles import fmt
from tests.reports.conftest import pdf_text
from tests.reports.synth_run import Part, make_run

REPO = Path(__file__).resolve().parents[2]
PRODUCT = REPO / "config" / "products" / "gyr130.yaml"

# The longest names the procedures make: chamber -100..200 C and supply up to 100 V with
# six significant digits (procedures/runtime/conditions.py), verification up to +/-20,000 deg/s.
CONDITIONS = [Condition(-99.9999, 99.9999).name, Condition(-12.3457, 4.75).name,
              "verify@-20000dps", "verify@-150dps"]
LONG_VALUES = [-0.000123456789, -123456.789012, -1.23456789e-11, 98765.4321]
LONG_U = [98765.4321, 1.23456789e-07, 0.000123456789, 1234567.0]


def _outcome(value: float, low: float | None, high: float | None) -> Outcome:
    inside = (low is None or value >= low) and (high is None or value <= high)
    return Outcome.PASS if inside else Outcome.FAIL


def edge_measurements() -> list[Measurement]:
    """Each product limit at its edges and with the longest values, at long conditions."""
    limits = yaml.safe_load(PRODUCT.read_text(encoding="utf-8"))["limits"]
    out = []
    for i, (name, lim) in enumerate(limits.items()):
        low, high = lim.get("low"), lim.get("high")
        edges = [v for e in (low, high) if e is not None
                 for v in (e, e - abs(e) * 1e-6 - 1e-9, e + abs(e) * 1e-6 + 1e-9)]
        values = edges + [LONG_VALUES[i % len(LONG_VALUES)]]
        for j, value in enumerate(values):
            out.append(Measurement(
                name=name, condition=CONDITIONS[(i + j) % len(CONDITIONS)], value=value,
                units=str(lim.get("units", "")), low=low, high=high,
                uncertainty_k2=LONG_U[(i + j) % len(LONG_U)],
                outcome=_outcome(value, low, high)))
    return out


def third_order_calibration() -> dict[str, Any]:
    c = {k: {"value": v, "uncertainty_k2": u} for k, v, u in [
        ("bias_dps", -0.000123456789, 98765.4321),
        ("bias_temp_coeff_dps_per_c", -0.0002807581234, 1.54321e-06),
        ("bias_supply_coeff_dps_per_v", -123456.789012, 1234567.0),
        ("scale", 1.02345678912, 2.7912345e-05),
        ("scale_temp_coeff_per_c", -0.000280758123, 1.5432e-06),
        ("scale_supply_coeff_per_v", -0.000696952123, 6.1312e-05),
        ("bias_temp_coeff2_dps_per_c2", -1.23456789e-05, 2.3456789e-06),
        ("bias_temp_coeff3_dps_per_c3", -9.87654321e-08, 1.23456789e-08),
        ("scale_temp_coeff2_per_c2", -3.45678912e-07, 4.5678912e-08),
        ("scale_temp_coeff3_per_c3", -5.67891234e-09, 6.7891234e-10),
    ]}
    return {**c, "reference_temperature_c": 25.0, "reference_supply_v": 5.0, "fit_order": 3,
            "readback_ok": True,
            "readback": {"bias_dps": -0.000123456789, "bias_tc2_dps_per_c2": -1.23456789e-05,
                         "bias_tc3_dps_per_c3": -9.87654321e-08,
                         "scale_tc2_per_c2": -3.45678912e-07,
                         "scale_tc3_per_c3": -5.67891234e-09}}


def temperature_fit(cal: dict[str, Any]) -> dict[str, Any]:
    names = [k for k in cal if isinstance(cal[k], dict) and "value" in cal[k]
             and k != "fit_order"]
    points = [{"condition": n, "bias_temp_c": t, "scale_temp_c": t, "supply_v": v,
               "bias_dps": 0.1 * t, "u_bias_dps": 0.01, "scale": 1.0 + 1e-4 * t, "u_scale": 1e-5}
              for n, t, v in [("T-40_V4.75", -40.0, 4.75), ("T25_V5.25", 25.0, 5.25),
                              ("T85_V4.75", 85.0, 4.75), ("T125_V5.25", 125.0, 5.25)]]
    return {"order": 3, "reference_temperature_c": 25.0, "reference_supply_v": 5.0,
            "coefficients": [{"name": n, "value": cal[n]["value"],
                              "uncertainty_k2": cal[n]["uncertainty_k2"],
                              "units": "deg/s" if n.startswith("bias") else "1"}
                             for n in names],
            "bias_params": [0.1, 1e-3, 1e-5, 1e-7, 0.01],
            "scale_params": [1.0, 1e-4, 1e-6, 1e-8, 1e-3],
            "bias_chi2": 1.23, "scale_chi2": 0.45, "dof": 0, "points": points}


@pytest.fixture(scope="module")
def edge_certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    folder, record = make_run(tmp_path_factory.mktemp("edge"), Part(serial="SIM-EDGE-1"))
    record.measurements = edge_measurements()
    record.failed_measurements = sorted({m.name for m in record.measurements
                                         if m.outcome is Outcome.FAIL})
    cal = third_order_calibration()
    record.calibration = Calibration.model_validate(cal)
    record.analysis.temperature_fit = TemperatureFitResults.model_validate(temperature_fit(cal))
    record.conditions = [ConditionRecord(
        name=name, temperature_c=-99.9999, supply_v=99.9999, die_temperature_c=-98.765432,
        supply_current_a=0.0123456789, time_to_stability_s=86399.5, stable=True)
        for name in CONDITIONS[:2]]
    record.verification = Verification.model_validate({
        "max_error_pct": -0.000123456789, "residuals": [
            {"condition": name, "rate_in_dps": -19999.9876, "error_dps": -0.000123456789,
             "error_pct": -123.456789} for name in CONDITIONS[2:]]})
    write_record(folder, record)
    render_certificate(folder)
    return folder, record


def _lines(folder: Path) -> list[list[str]]:
    return [line.split() for line in pdf_text(folder / "certificate.pdf").splitlines()]


def _adjacent(lines: list[list[str]], first: str, second: str) -> bool:
    return any(tokens[i] == first and tokens[i + 1] == second
               for tokens in lines for i in range(len(tokens) - 1))


def test_every_value_and_uncertainty_is_its_own_token(edge_certificate: tuple[Path, Any]) -> None:
    folder, record = edge_certificate
    text = pdf_text(folder / "certificate.pdf")
    results = text[text.index("Results\n"):text.index("Calibration written to the part")]
    lines = [line.split() for line in results.splitlines()]
    # each row: its condition, value and uncertainty side by side on one line, each whole
    missing = [f"{m.condition} {fmt(m.value)} {fmt(m.uncertainty_k2, 3)} ({m.name})"
               for m in record.measurements
               if not any(tokens[i:i + 3] == [m.condition, fmt(m.value),
                                              fmt(m.uncertainty_k2, 3)]
                          for tokens in lines for i in range(len(tokens)))]
    assert not missing, missing
    tokens = {t for line in lines for t in line}
    names = {m.name for m in record.measurements} | {
        word for m in record.measurements if m.units != "1" for word in m.units.split()}
    assert names - tokens == set()  # never broken inside a name or a unit
    assert {"Outcome", "Measurement", "Condition"} <= tokens


def test_calibration_shows_every_term_to_third_order_as_tokens(
        edge_certificate: tuple[Path, Any]) -> None:
    folder, _ = edge_certificate
    text = pdf_text(folder / "certificate.pdf")
    section = text[text.index("Calibration written to the part"):
                   text.index("Verification after correction")]
    lines = [line.split() for line in section.splitlines()]
    cal = third_order_calibration()
    terms = [k for k, v in cal.items() if isinstance(v, dict) and "value" in v]
    assert len(terms) == 10
    for key in terms:  # finding 13: the programmed tc2 and tc3 are in the section
        value, u = cal[key]["value"], cal[key]["uncertainty_k2"]
        row = next((t for t in lines if t and key in t), None)
        assert row is not None, key
        i = row.index(key)
        assert row[i + 1:i + 3] == [fmt(value, 7), fmt(u, 3)], (key, row)
    for register, value in cal["readback"].items():  # read back, in its own column
        assert any(t and t[-1] == fmt(value, 7) for t in lines), register


def test_conditions_and_verification_numbers_are_tokens(
        edge_certificate: tuple[Path, Any]) -> None:
    folder, _ = edge_certificate
    lines = _lines(folder)
    row = next(t for t in lines if t and t[0] == CONDITIONS[0])
    assert row[1:] == [fmt(-99.9999), fmt(-98.765432), fmt(99.9999), "-", fmt(0.0123456789),
                       fmt(86399.5), "yes"]
    for name in CONDITIONS[2:]:
        row = next(t for t in lines if t and t[0] == name and len(t) == 4)
        assert row[1:] == [fmt(-19999.9876), fmt(-0.000123456789, 3), fmt(-123.456789, 3)]


def test_a_fail_row_keeps_its_margin_apart_from_its_outcome(
        edge_certificate: tuple[Path, Any]) -> None:
    folder, _ = edge_certificate
    text = pdf_text(folder / "certificate.pdf")
    assert "%FAIL" not in text and "%PASS" not in text
