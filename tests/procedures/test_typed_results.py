"""Typed step results (issue 27): record.analysis and record.verification are the models of
procedures/runtime/results.py, record format gyrocal-record/2.

- a full run's certificate draws every section the record holds (none says "not in the
  record" / "not recorded" / "Not drawn");
- a misspelled or unknown key in a format-2 section is refused when the record is read;
- a format-1 record (free dicts) is read through the converter: a real one from the code
  before the change gives back the same JSON, and a sealed format-1 folder with odd keys
  still renders and `station verify` passes, its record.json bytes untouched.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from procedures.runtime.record import (
    RECORD_FILE,
    RECORD_FORMAT,
    RECORD_FORMAT_1,
    RunRecord,
    Verdict,
    read_record,
)
from procedures.runtime.results import AllanResults, Analysis, Section, Verification
from procedures.steps.registry import step_types
from reports.certificate import certificate_bytes
from station.manifest import seal
from station.settings import LoadedSettings
from station.signing_keys import load_or_create_identity
from station.station_file import load_settings
from tests.reports.conftest import pdf_text
from tests.reports.test_signing import station, station_file

ROOT = Path(__file__).resolve().parents[2]
# record.json of `station demo` made by the code before record format 2 (main at 6b59095,
# run from a clone in /tmp/res-before, hence its paths): a real format-1 record
DEMO_FORMAT_1 = ROOT / "tests" / "data" / "records" / "demo-format-1.json"
NOT_THERE = ("not in the record", "not recorded", "Not drawn", "record.analysis has no")


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory) -> LoadedSettings:
    return load_settings(station_file(tmp_path_factory.mktemp("station")))


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory, settings: LoadedSettings) -> Path:
    """The demo's run (the full rate-table procedure, SIM-0001, lockstep), sealed."""
    from station.sim_run import run_simulated

    result, _ = run_simulated(
        [{"socket": 1, "serial": "SIM-0001"}],
        procedure_path=ROOT / "config" / "procedures" / "eol-rate-table.yaml",
        out=tmp_path_factory.mktemp("demo"), settings=settings, certificate=True,
    )
    assert result.verdicts[1] is Verdict.PASS, result.reasons
    return result.folders[1]


def _json(folder: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((folder / RECORD_FILE).read_text(encoding="utf-8"))
    return data


def _write(folder: Path, data: dict[str, Any]) -> None:
    (folder / RECORD_FILE).write_text(json.dumps(data, indent=2), encoding="utf-8")


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    return Path(shutil.copytree(src, dst / src.name))


def test_a_full_run_is_format_2_and_its_certificate_draws_every_section(
    demo_run: Path,
) -> None:
    rec = read_record(demo_run)
    assert rec.format == RECORD_FORMAT == "gyrocal-record/2"
    a = rec.analysis
    assert a.allan is not None and len(a.allan.tau_s) >= 2
    assert len(a.rate_table) == len(a.stop_method) == len(a.stability) == 4
    assert rec.verification is not None and rec.verification.residuals
    text = pdf_text(demo_run / "certificate.pdf")
    for phrase in NOT_THERE:
        assert phrase not in text, phrase
    for heading in ("Noise: Allan deviation", "Rate table: output versus input, residuals",
                    "Verification after correction", "Thermal stabilisation"):
        assert heading in text
    # these two are sentences in wrapped paragraphs: where a line breaks depends on the
    # run's numbers, so they are looked for in the text with its line breaks undone
    flowing = " ".join(pdf_text(demo_run / "certificate.pdf", layout=False).split())
    assert "Largest verification error" in flowing and "read-back PASSED" in flowing


@pytest.mark.parametrize(("where", "rename"), [
    ("allan", ("arw_deg_per_sqrt_h", "arw_deg_per_sqrth")),
    ("stop_method", ("scale_correction", "scale_corection")),
    ("verification", ("max_error_pct", "max_err_pct")),
    ("analysis", ("stability", "stabilty")),
])
def test_a_misspelled_key_in_a_format_2_record_is_refused_naming_it(
    demo_run: Path, tmp_path: Path, where: str, rename: tuple[str, str]
) -> None:
    folder = _copy(demo_run, tmp_path)
    data = _json(folder)
    old, new = rename
    section = {"allan": data["analysis"]["allan"],
               "stop_method": next(iter(data["analysis"]["stop_method"].values())),
               "verification": data["verification"], "analysis": data["analysis"]}[where]
    section[new] = section.pop(old)
    _write(folder, data)
    with pytest.raises(ValueError, match=new):
        read_record(folder)
    # the same record as format 1 passes through the converter, the key dropped
    data["format"] = RECORD_FORMAT_1
    _write(folder, data)
    assert read_record(folder).format == RECORD_FORMAT_1


def test_a_model_refuses_a_field_it_does_not_declare() -> None:
    with pytest.raises(ValidationError, match="arw_deg_per_sqrth"):
        AllanResults(condition="T25_V4.75", arw_deg_per_sqrth=0.2)  # type: ignore[call-arg]


def test_mypy_catches_a_writer_that_misspells_a_field(tmp_path: Path) -> None:
    """What test_code_quality's mypy run reports when a step's writer and its Results model
    disagree on a name."""
    snippet = tmp_path / "writer.py"
    snippet.write_text("from procedures.runtime.results import AllanResults\n\n"
                       "AllanResults(condition='T25', arw_deg_per_sqrth=0.2)\n")
    done = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-incremental", "--follow-imports=silent",
         str(snippet)], cwd=ROOT, capture_output=True, text=True, check=False)
    assert done.returncode == 1, done.stdout
    assert 'Unexpected keyword argument "arw_deg_per_sqrth"' in done.stdout


def test_a_real_format_1_record_reads_back_to_the_same_json() -> None:
    raw = json.loads(DEMO_FORMAT_1.read_text(encoding="utf-8"))
    assert raw["format"] == RECORD_FORMAT_1
    rec = RunRecord.model_validate(raw)
    assert rec.format == RECORD_FORMAT_1
    assert rec.analysis.allan is not None and rec.analysis.allan.condition == "T25_V4.75"
    assert rec.verification is not None
    assert len(rec.verification.residuals) == len(raw["verification"]["residuals"]) == 4
    assert rec.model_dump(mode="json") == raw  # every key and number as format 1 wrote it
    # and as format 2 it is the same record too
    assert RunRecord.model_validate({**raw, "format": RECORD_FORMAT}).model_dump(
        mode="json") == {**raw, "format": RECORD_FORMAT}


def test_an_odd_format_1_folder_renders_and_verifies_without_being_rewritten(
    demo_run: Path, tmp_path: Path, settings: LoadedSettings
) -> None:
    folder = _copy(demo_run, tmp_path)
    data = _json(folder)
    data["format"] = RECORD_FORMAT_1
    data["analysis"]["legacy_summary"] = {"anything": [1, 2]}  # a key format 2 never had
    del data["analysis"]["allan"]["record_s"]  # a key missing
    data["analysis"]["stop_method"]["T25_V4.75"]["old_field"] = "x"  # an unknown key
    data["analysis"]["stability"]["T45_V5.25"] = "not a mapping"  # an odd entry
    rows = len(data["verification"]["residuals"])
    data["verification"]["residuals"].append({"rate_in_dps": 1.0})  # a row without condition
    _write(folder, data)
    identity = load_or_create_identity(
        settings.resolve(settings.settings.signing.key),
        settings.resolve(settings.settings.signing.certificate), "unused")
    seal(folder, identity, "run")
    before = (folder / RECORD_FILE).read_bytes()

    rec = read_record(folder)
    assert "T45_V5.25" not in rec.analysis.stability and len(rec.analysis.stability) == 3
    assert rec.analysis.allan is not None and "record_s" not in rec.analysis.allan.model_dump()
    assert rec.verification is not None and len(rec.verification.residuals) == rows
    code, out, _ = station("verify", str(folder), "--station", str(settings.source.path))
    assert code == 0 and "intact" in out, out
    rendered = tmp_path / "re-rendered.pdf"  # beside the folder: its own pdf stays sealed
    rendered.write_bytes(certificate_bytes(folder))
    text = pdf_text(rendered)
    assert "Noise: Allan deviation" in text and "Largest verification error" in text
    assert "Not drawn" not in text
    assert (folder / RECORD_FILE).read_bytes() == before  # reading converts, never rewrites
    code, out, _ = station("verify", str(folder), "--station", str(settings.source.path))
    assert code == 0, out


def test_every_step_type_that_records_a_section_declares_its_results_model() -> None:
    """Each step type's `Results` is one of the models record.analysis (or .verification)
    holds: a step's section is declared once, where the step is."""
    held: set[type] = {Verification}
    for info in Analysis.model_fields.values():
        held |= _models_in(info.annotation)
    declared = {name: cls.Results for name, cls in step_types().items()
                if cls.Results is not None}
    assert {"bias", "thermal", "rate_table", "stop_method", "manual_stop", "fit", "program",
            "program_three_axis", "verify", "verify_stop", "fit_three_axis", "warm_up",
            "turn_on_repeatability", "positions"} <= set(declared)
    for name, model in declared.items():
        assert issubclass(model, Section) and model in held, name


def _models_in(annotation: Any) -> set[type]:
    from typing import get_args

    if isinstance(annotation, type) and issubclass(annotation, Section):
        return {annotation}
    out: set[type] = set()
    for arg in get_args(annotation):
        out |= _models_in(arg)
    return out


def test_the_measured_supply_and_higher_order_terms_are_declared_fields() -> None:
    """The certificate's "Supply measured" column and its higher-order coefficient rows read
    declared fields, not undeclared extras: the first-order demo record keeps its JSON (no
    higher-order keys), a second-order calibration shows its terms, and a malformed term in
    a format-1 record is dropped instead of refusing the record."""
    from reports.cert_sections import calibration_terms

    raw = json.loads(DEMO_FORMAT_1.read_text(encoding="utf-8"))
    rec = RunRecord.model_validate(raw)
    assert rec.conditions[0].supply_measured_v == raw["conditions"][0]["supply_measured_v"]
    assert not rec.conditions[0].model_extra and not rec.calibration.model_extra  # type: ignore[union-attr]
    assert rec.model_dump(mode="json")["calibration"] == raw["calibration"]
    assert [t[0] for t in calibration_terms(rec.calibration)].count("scale") == 1  # type: ignore[arg-type]

    term = {"value": 1.5e-5, "uncertainty_k2": 2e-6}
    second = {**raw["calibration"], "bias_temp_coeff2_dps_per_c2": term}
    rec2 = RunRecord.model_validate({**raw, "format": RECORD_FORMAT, "calibration": second})
    assert rec2.calibration is not None
    assert rec2.calibration.bias_temp_coeff2_dps_per_c2 is not None
    keys = [t[0] for t in calibration_terms(rec2.calibration)]
    assert keys.index("bias_temp_coeff2_dps_per_c2") == keys.index("bias_temp_coeff_dps_per_c") + 1
    assert rec2.model_dump(mode="json")["calibration"] == second

    broken = {**raw["calibration"], "scale_temp_coeff2_per_c2": {"value": "x"}}
    rec1 = RunRecord.model_validate({**raw, "calibration": broken})  # format 1: dropped
    assert rec1.calibration is not None and rec1.calibration.scale_temp_coeff2_per_c2 is None
    with pytest.raises(ValidationError, match="scale_temp_coeff2_per_c2"):
        RunRecord.model_validate({**raw, "format": RECORD_FORMAT, "calibration": broken})
