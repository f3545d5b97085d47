"""The certificate: content a quality engineer signs off from, vector-only, reproducible."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from procedures.runtime.record import Verdict, read_record, write_record
from procedures.runtime.results import Analysis, ProgrammingResults
from reports.certificate import certificate_bytes, render_certificate
from reports.styles import fmt
from tests.reports.conftest import need_poppler, pdf_pages, pdf_text


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def test_pass_certificate_names_serial_verdict_and_every_measurement(pass_run: Path) -> None:
    pdf = pass_run / "certificate.pdf"
    text = pdf_text(pdf)
    record = read_record(pass_run)
    assert "SIM-PASS-1" in text
    page1 = pdf_text(pdf, page=1)
    assert re.search(r"^\s*PASS\s*$", page1, re.M), "verdict banner missing on page one"
    assert "Failing measurements" not in page1 and "Reason:" not in page1
    lines = text.splitlines()
    for m in record.measurements:
        # the value on the same line as the name, in the results table
        assert any(m.name in ln and fmt(m.value) in ln.split() for ln in lines), m.name


def test_fail_certificate_names_the_failing_measurement_on_page_one(fail_run: Path) -> None:
    pdf = fail_run / "certificate.pdf"
    page1 = _flat(pdf_text(pdf, page=1))
    assert "SIM-FAIL-2" in page1
    assert re.search(r"\bFAIL\b", page1)
    assert "Failing measurements: bias_dps = 12.5 deg/s (limits -10 .. 10)" in page1
    # the passing measurements are not named as failing
    failing_line = page1.split("Failing measurements:")[1].split("INSTRUMENT")[0]
    assert "scale_temp_coeff_per_c" not in failing_line
    text = pdf_text(pdf)
    for m in read_record(fail_run).measurements:
        assert any(m.name in ln and fmt(m.value) in ln.split() for ln in text.splitlines())


def test_page_one_summarises_how_tested_and_the_outcome(fail_run: Path) -> None:
    page1 = _flat(pdf_text(fail_run / "certificate.pdf", page=1))
    rec = read_record(fail_run)
    n_fail = sum(m.outcome.value == "FAIL" for m in rec.measurements)
    n_marg = sum(m.outcome.value == "MARGINAL" for m in rec.measurements)
    assert (n_fail, n_marg) == (1, 1)
    assert f"{len(rec.measurements)} measurements: {n_fail} failed, {n_marg} marginal" in page1
    assert "4 conditions (25/45 C, 4.75/5.25 V)" in page1
    assert "read-back PASSED" in page1
    conditions = [ln for ln in pdf_text(fail_run / "certificate.pdf", page=1).splitlines()
                  if ln.strip().startswith("T45_V5.25 ")]
    assert conditions and conditions[0].split()[1:5] == ["45", "46.2", "5.25", "5.2496"]


def test_overdue_instrument_is_stated_on_page_one(fail_run: Path, pass_run: Path) -> None:
    assert "CALIBRATION OVERDUE" in pdf_text(fail_run / "certificate.pdf", page=1)
    assert "chamber" in pdf_text(fail_run / "certificate.pdf", page=1)
    assert "OVERDUE" not in pdf_text(pass_run / "certificate.pdf")


def test_traceability_shows_hashes_instruments_and_times(pass_run: Path) -> None:
    text = _flat(pdf_text(pass_run / "certificate.pdf", layout=False))
    rec = read_record(pass_run)
    assert rec.raw_data is not None
    for sha in (rec.procedure.sha256, rec.product.sha256, rec.raw_data.sha256):
        assert sha in text.replace(" ", "")
    for inst in rec.instruments:
        assert inst.serial in text and str(inst.calibration_due) in text
    assert "2026-11-21 09:30:00 UTC" in text
    assert "10:30:00 CET (Europe/Berlin)" in text  # station local time
    assert "EOL-03" in text and "A. Tester" in text and "0.1.0+test" in text


def test_every_page_renders_numbered_and_marked_simulated(pass_run: Path, tmp_path: Path) -> None:
    pdf = pass_run / "certificate.pdf"
    n = pdf_pages(pdf)
    assert n >= 3
    subprocess.run(["pdftoppm", "-r", "30", "-png", str(pdf), str(tmp_path / "p")], check=True)
    pngs = sorted(tmp_path.glob("p-*.png"))
    assert len(pngs) == n
    assert all(p.stat().st_size > 1000 for p in pngs)
    for i in range(1, n + 1):
        page = pdf_text(pdf, page=i)
        assert f"page {i} of {n}" in page
        assert "SIMULATED BENCH" in page


def test_real_bench_run_carries_no_simulated_mark(tmp_path: Path, pass_run: Path) -> None:
    folder = tmp_path / pass_run.name
    shutil.copytree(pass_run, folder)
    rec = read_record(folder)
    write_record(folder, rec.model_copy(update={"simulated": False}))
    text = pdf_text(render_certificate(folder))
    assert "SIMULATED" not in text
    assert "real instruments" in text


def test_a_model_twin_s_certificate_names_the_effects_its_part_carries(
    tmp_path: Path, pass_run: Path
) -> None:
    """A simulated part declared to carry a model's effects (`station discrepancy
    --simulate`'s twin) says which on page one; any other part has no such line."""
    folder = tmp_path / pass_run.name
    shutil.copytree(pass_run, folder)
    rec = read_record(folder)
    effects = ["bias_temperature", "scale_temperature", "lib_w_dTdt"]
    write_record(folder, rec.model_copy(update={"simulated_part_effects": effects}))
    page1 = _flat(pdf_text(render_certificate(folder), page=1))
    assert ("Simulated part a model's twin; effects it carries: bias_temperature, "
            "scale_temperature, lib_w_dTdt") in page1
    write_record(folder, rec.model_copy(update={"simulated_part_effects": []}))
    assert "effects it carries: none (bias and scale only)" in _flat(
        pdf_text(render_certificate(folder), page=1))
    assert "Simulated part" not in _flat(pdf_text(pass_run / "certificate.pdf", page=1))
    assert "simulated_part_effects" not in (pass_run / "record.json").read_text()


def test_certificate_holds_no_raster_image(pass_run: Path) -> None:
    need_poppler()
    pdf = pass_run / "certificate.pdf"
    listing = subprocess.run(["pdfimages", "-list", str(pdf)], capture_output=True, text=True,
                             check=True).stdout.splitlines()
    assert len(listing) == 2, listing  # header lines only, no image rows
    assert b"/Subtype /Image" not in pdf.read_bytes()


def test_plots_are_drawn_with_their_captions(pass_run: Path) -> None:
    text = _flat(pdf_text(pass_run / "certificate.pdf", layout=False))
    for title in ("Stop method, condition T25_V4.75", "Output versus input",
                  "Residual from the fitted line", "Allan deviation T25_V5.25", "Die temperature",
                  "static (bias) window", "integration window", "ARW 0.6 deg/sqrt(h)",
                  "criterion band 0.2 C", "Reviewed by (quality)", "RRW 30 deg/h/sqrt(h)",
                  "bias instability 12 deg/h (x 0.664)",
                  "T25_V4.75, T25_V5.25, T45_V4.75, T45_V5.25: peak-to-peak below 0.2 C and "
                  "|slope| below 0.05 C/min over the last 60 s"):
        assert title in text, title
    assert "Not drawn" not in text


def test_calibration_section_states_sign_conventions_and_readback(pass_run: Path) -> None:
    text = _flat(pdf_text(pass_run / "certificate.pdf", layout=False))
    assert "bias correction is minus the bias (-3.1 deg/s here)" in text
    assert f"input divided by output ({fmt(1 / 1.021)} here)" in text
    assert "Read-back check: PASSED" in text
    assert "k = 2" in text


def test_rendering_twice_gives_identical_bytes_anywhere(pass_run: Path, tmp_path: Path) -> None:
    first = certificate_bytes(pass_run)
    assert certificate_bytes(pass_run) == first
    moved = tmp_path / "elsewhere" / pass_run.name
    shutil.copytree(pass_run, moved)
    assert certificate_bytes(moved) == first  # no machine or path dependence
    assert b"D:20261121100100+00'00'" in first  # dated by the run, not by now


def test_missing_raw_data_gives_error_certificate_saying_what_is_missing(fresh_run: Path) -> None:
    (fresh_run / "raw.h5").unlink()
    pdf = render_certificate(fresh_run)
    page1 = _flat(pdf_text(pdf, page=1))
    assert re.search(r"\bERROR\b", page1)
    assert "raw data file raw.h5 is missing" in page1
    assert "the run itself recorded PASS" in page1
    assert "Not drawn" in _flat(pdf_text(pdf))


def test_corrupt_raw_data_gives_error_certificate(fresh_run: Path) -> None:
    (fresh_run / "raw.h5").write_bytes(b"\x89HDF garbage, truncated by a crash")
    page1 = _flat(pdf_text(render_certificate(fresh_run), page=1))
    assert "ERROR" in page1 and "raw data unreadable" in page1
    assert "does not match the SHA-256" in page1


def test_altered_raw_data_is_caught_by_its_hash(fresh_run: Path) -> None:
    rec = read_record(fresh_run)
    assert rec.raw_data is not None
    write_record(fresh_run, rec.model_copy(update={
        "raw_data": rec.raw_data.model_copy(update={"sha256": "0" * 64})}))
    page1 = _flat(pdf_text(render_certificate(fresh_run), page=1))
    assert "ERROR" in page1 and "does not match the SHA-256 in record.json" in page1


@pytest.mark.parametrize("damage", ["missing", "not json", "not a record"])
def test_broken_record_gives_error_certificate(fresh_run: Path, damage: str) -> None:
    path = fresh_run / "record.json"
    if damage == "missing":
        path.unlink()
    elif damage == "not json":
        path.write_text('{"run_id": "x", ', encoding="utf-8")
    else:
        path.write_text('{"run_id": "x"}', encoding="utf-8")
    pdf = render_certificate(fresh_run)
    page1 = _flat(pdf_text(pdf, page=1))
    assert "ERROR" in page1
    expected = {"missing": "no record.json", "not json": "not valid JSON",
                "not a record": "not a valid run record"}[damage]
    assert expected in page1
    assert pdf_pages(pdf) >= 1


def test_aborted_run_states_its_reason(tmp_path: Path) -> None:
    from tests.reports.synth_run import Part, make_run

    folder, _ = make_run(tmp_path, Part(serial="SIM-ABT-4", verdict="ABORTED"))
    page1 = _flat(pdf_text(render_certificate(folder), page=1))
    assert "ABORTED" in page1 and "Reason: operator pressed stop" in page1


def test_missing_analysis_draws_boxes_saying_why(fresh_run: Path) -> None:
    rec = read_record(fresh_run)
    write_record(fresh_run, rec.model_copy(update={"analysis": Analysis()}))
    text = _flat(pdf_text(render_certificate(fresh_run), layout=False))
    assert "Not drawn: record.analysis['allan'] is not in the record" in text
    # rate-table and stop-method plots fall back to raw.h5
    assert "computed from raw.h5 plateau means" in text
    assert "Stop method, condition T45_V5.25" in text
    assert re.search(r"\bPASS\b", text)


def test_unfinished_run_is_an_error_certificate(fresh_run: Path) -> None:
    rec = read_record(fresh_run)
    write_record(fresh_run, rec.model_copy(update={"verdict": Verdict.RUNNING,
                                                   "finished_utc": None}))
    page1 = _flat(pdf_text(render_certificate(fresh_run), page=1))
    assert "ERROR" in page1 and "never finished" in page1 and "RUNNING" in page1


@pytest.mark.filterwarnings("error::UserWarning")  # e.g. pydantic's serializer warning
def test_unmeasured_values_and_markup_in_text_render(fresh_run: Path) -> None:
    from procedures.runtime.record import Measurement, Outcome

    rec = read_record(fresh_run)
    extra = Measurement(name="g_sensitivity_<dps/g>", value=None, units="deg/s/g", low=0.0,
                        high=0.02, outcome=Outcome.NOT_MEASURED)
    write_record(fresh_run, rec.model_copy(update={
        # model_copy does not validate: give the enum, not the string "ABORTED"
        "verdict": Verdict.ABORTED, "reason": "operator <stop> & e-stop",
        "measurements": [*rec.measurements, extra]}))
    text = _flat(pdf_text(render_certificate(fresh_run), layout=False))
    assert "operator <stop> & e-stop" in text
    assert "g_sensitivity_<dps/g>" in text and "NOT MEASURED" in text


def test_error_run_still_names_measurements_already_failed(tmp_path: Path) -> None:
    from tests.reports.synth_run import Part, make_run

    folder, _ = make_run(tmp_path, Part(serial="SIM-ERR-5", verdict="ERROR", bias_dps=12.5))
    page1 = _flat(pdf_text(render_certificate(folder), page=1))
    assert "Reason: operator pressed stop" in page1
    assert "Measurements already outside their limits: bias_dps = 12.5 deg/s" in page1


@pytest.mark.parametrize("spelling", ["register", "record"])
def test_read_back_column_shows_every_coefficient_read_back(fresh_run: Path,
                                                            spelling: str) -> None:
    """The readback dict uses the part's register names (program step); older records may
    use the record's keys. Either way no coefficient may look unverified ('-')."""
    rec = read_record(fresh_run)
    assert rec.calibration is not None
    registers = {"bias_dps": "bias_dps", "scale": "scale",
                 "bias_temp_coeff_dps_per_c": "bias_tc_dps_per_c",
                 "scale_temp_coeff_per_c": "scale_tc_per_c",
                 "bias_supply_coeff_dps_per_v": "bias_vc_dps_per_v",
                 "scale_supply_coeff_per_v": "scale_vc_per_v"}
    # read-back values distinct from the written ones, so the column cannot echo "Value"
    readback = {(reg if spelling == "register" else key): 1000.0 + i
                for i, (key, reg) in enumerate(registers.items())}
    write_record(fresh_run, rec.model_copy(update={"calibration": rec.calibration.model_copy(
        update={"readback": readback})}))
    text = pdf_text(render_certificate(fresh_run))
    table = text.split("Calibration written to the part")[1].split("Reference conditions")[0]
    for i, key in enumerate(registers):
        row = next(ln.split() for ln in table.splitlines() if key in ln.split())
        assert row[-1] == fmt(1000.0 + i, 7), (key, row)


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_certificate_and_record_are_readable_by_others_as_the_umask_allows(
        fresh_run: Path, umask: int) -> None:
    """mkstemp makes 0600 files; the run folder's files get the ordinary mode (as raw.h5)."""
    import stat

    old = os.umask(umask)
    try:
        write_record(fresh_run, read_record(fresh_run))
        pdf = render_certificate(fresh_run)
    finally:
        os.umask(old)
    for path in (pdf, fresh_run / "record.json"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask, path.name


def test_dimensionless_values_carry_no_stray_unit(tmp_path: Path) -> None:
    from tests.reports.synth_run import Part, make_run

    folder, rec = make_run(tmp_path, Part(serial="SIM-SCL-6", bias_dps=1.0, scale=1.08))
    assert rec.failed_measurements == ["scale"]
    assert next(m.units for m in rec.measurements if m.name == "scale") == "1"
    page1 = _flat(pdf_text(render_certificate(folder), page=1))
    assert "Failing measurements: scale = 1.08 (limits 0.94 .. 1.06)" in page1
    lines = pdf_text(folder / "certificate.pdf").splitlines()
    scale_row = next(ln for ln in lines if ln.split()[:1] == ["scale"] and "FAIL" in ln)
    assert "(ratio)" in scale_row and " 1 " not in scale_row


def test_a_part_not_programmed_is_not_said_to_be_written(fresh_run: Path) -> None:
    """A part failing before the program step keeps its fitted coefficients in the record;
    the certificate must not call them written to the part."""
    rec = read_record(fresh_run)
    reason = "not programmed: failed stop_table_consistency@T25_V4.75"
    analysis = rec.analysis.model_copy()
    analysis.programming = ProgrammingResults(programmed=False, reason=reason)
    write_record(fresh_run, rec.model_copy(update={"analysis": analysis,
                                                   "verdict": Verdict.FAIL}))
    text = _flat(pdf_text(render_certificate(fresh_run), layout=False))
    assert "Calibration written" not in text
    assert "Calibration fitted but not written to the part (failed stop_table_consistency" in text
    assert "Calibration fitted (not written to the part)" in text
    assert "failed failed" not in text and "Read-back check: none (not written)" in text
