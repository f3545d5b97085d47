"""The certificate's temperature-fit section: coefficients with uncertainties and the two
plots, drawn from record.analysis["temperature_fit"]; absent without it, a box when broken."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from procedures.analysis.temp_fit import fit_temperature, record_summary
from procedures.analysis.temp_supply_fit import ConditionMeasurement
from procedures.runtime.record import RECORD_FILE, RECORD_FORMAT_1, read_record
from reports.certificate import certificate_bytes, render_certificate
from tests.reports.conftest import pdf_text
from tests.reports.synth_run import Part, make_run

TEMPS = (-10.0, 25.0, 60.0)


def _summary(order: int = 2) -> dict:
    rng = np.random.default_rng(4)
    conds, points = [], []
    for t in TEMPS:
        for v in (4.75, 5.25):
            dt, dv = t - 25.0, v - 5.0
            bias = 1.2 + 0.008 * dt - 1.5e-4 * dt**2 + 0.05 * dv + 0.002 * rng.standard_normal()
            scale = 1.01 * (1 + 2e-4 * dt - 3e-6 * dt**2 + 1e-3 * dv)
            conds.append(ConditionMeasurement(t, v, bias, 0.002, scale, 3e-5))
            points.append({"condition": f"T{t:g}_V{v:g}", "bias_temp_c": t, "scale_temp_c": t,
                           "supply_v": v, "bias_dps": bias, "u_bias_dps": 0.002,
                           "scale": scale, "u_scale": 3e-5})
    fit = fit_temperature(conds, order)
    return record_summary(fit, fit, points)


def _with_fit(root: Path, serial: str, fit: object, record_format: str = "") -> Path:
    folder, _ = make_run(root, Part(serial=serial))
    data = json.loads((folder / RECORD_FILE).read_text())
    data["analysis"]["temperature_fit"] = fit
    if record_format:
        data["format"] = record_format
    (folder / RECORD_FILE).write_text(json.dumps(data))
    return folder


def test_second_order_fit_section_shows_every_coefficient(tmp_path: Path) -> None:
    summary = _summary(2)
    folder = _with_fit(tmp_path, "SIM-TF-1", summary)
    text = pdf_text(render_certificate(folder))
    assert "Temperature fit of bias and scale" in text
    assert "Second-order fit in temperature" in text
    for c in summary["coefficients"]:
        assert c["name"] in text
    assert "bias_temp_coeff2_dps_per_c2" in text and "scale_temp_coeff2_per_c2" in text
    assert "Bias against die temperature" in text and "Scale against die temperature" in text
    assert "fit at 4.75 V" in text and "fit at 5.25 V" in text
    # the page shows the value and its uncertainty as fitted
    b2 = next(c for c in summary["coefficients"] if c["name"] == "bias_temp_coeff2_dps_per_c2")
    assert f"{b2['value']:.4g}"[:5] in text.replace("−", "-")


def test_a_record_without_a_temperature_fit_has_no_section(pass_run: Path) -> None:
    text = pdf_text(pass_run / "certificate.pdf")
    assert "Temperature fit of bias and scale" not in text


def test_a_fit_that_cannot_be_drawn_says_so_and_the_certificate_is_still_issued(
    tmp_path: Path,
) -> None:
    folder = _with_fit(tmp_path, "SIM-TF-2", {**_summary(2), "bias_params": [1.0, 2.0]})
    text = pdf_text(render_certificate(folder))
    assert "Temperature fit of bias and scale" in text and "Not drawn:" in text
    assert "bias_params holds 2 values, not 4" in text


# Changed with record format 2: a section that does not match its model (a string, a fit
# without its keys, a point whose temperature is not a number) is refused when a format-2
# record is read, naming the key; in a format-1 record the converter drops that section and
# the certificate is issued without it (format 1 drew a "Not drawn" box instead).
BROKEN = ["not a mapping", {"order": 2}, {**_summary(2), "points": [{"bias_temp_c": "hot"}]}]


@pytest.mark.parametrize("broken", BROKEN)
def test_a_malformed_fit_in_a_format_2_record_is_refused_naming_it(
    tmp_path: Path, broken: object
) -> None:
    folder = _with_fit(tmp_path, "SIM-TF-4", broken)
    with pytest.raises(ValueError, match="temperature_fit"):
        read_record(folder)


@pytest.mark.parametrize("broken", BROKEN)
def test_a_malformed_fit_in_a_format_1_record_is_dropped_and_the_certificate_issued(
    tmp_path: Path, broken: object
) -> None:
    folder = _with_fit(tmp_path, "SIM-TF-5", broken, RECORD_FORMAT_1)
    assert read_record(folder).analysis.temperature_fit is None
    text = pdf_text(render_certificate(folder))
    assert "Calibration certificate" in text
    assert "Temperature fit of bias and scale" not in text


def test_the_section_renders_byte_identically_twice(tmp_path: Path) -> None:
    folder = _with_fit(tmp_path, "SIM-TF-3", _summary(3 if len(TEMPS) > 3 else 2))
    assert certificate_bytes(folder) == certificate_bytes(folder)
