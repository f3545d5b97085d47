"""`station discrepancy` as a new user meets it: where the results go, which part and run
folder they are of, paths checked before the analysis, what the console says, the CSV
export, the help text and docs, and the report's wording."""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
import sys
import zlib
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from fake_run_folder import write_run_folder
from helpers_model import TINY, as_trajectory
from synth_gyro import Part, generate

from procedures.model.data import CSV_COLUMNS, load_csv, write_csv
from procedures.model.run_folder import find_run_folder, load_data
from reports.charts import nice_ticks
from reports.discrepancy_report import step_axis_range
from station.cli import discrepancy as cli_discrepancy
from station.cli import main as cli

ROOT = Path(__file__).resolve().parents[2]
PINNED = {"gap_initial_dps", "noise_floor_dps", "iterations", "effects_added", "gap_final_dps"}


def _station(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "station", "discrepancy", *args],
                          capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def _pdf_text(pdf: bytes) -> str:
    """The page content streams of a reportlab PDF (ASCII85 + Flate), as text."""
    out = []
    for m in re.finditer(rb"/ASCII85Decode /FlateDecode \] /Length \d+\s*>>\s*stream\r?\n"
                         rb"(.*?)endstream", pdf, re.S):
        raw = m.group(1).strip().removesuffix(b"~>")
        out.append(zlib.decompress(base64.a85decode(raw)).decode("latin-1"))
    return "\n".join(out)


def _pdf_line(text: str, start: str) -> str:
    """The printed line of the PDF that begins with `start` (its Tj pieces joined)."""
    for line in text.splitlines():
        pieces = [re.sub(r"\\(.)", r"\1", p) for p in re.findall(r"\(((?:[^\\)]|\\.)*)\) Tj",
                                                                line)]
        if pieces and "".join(pieces).startswith(start):
            return "".join(pieces)
    raise AssertionError(f"no line starting {start!r} in the PDF")


@pytest.fixture(scope="module")
def tiny_run() -> dict[str, object]:
    return generate(Part(), 5, TINY)


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory, tiny_run: dict[str, object]) -> Path:
    """A results folder: three runs of SIM-0001 (not in date order on disk), one of
    SIM-0002; no hardware sync (an older fixture)."""
    root = tmp_path_factory.mktemp("res") / "results"
    first = write_run_folder(root / "20260102T000000Z_SIM-0001", tiny_run, serial="SIM-0001")
    shutil.copytree(first, root / "20260103T090000Z_SIM-0001")
    shutil.copytree(first, root / "20260101T120000Z_SIM-0001")
    write_run_folder(root / "20260104T000000Z_SIM-0002", tiny_run, serial="SIM-0002")
    return root


def test_folder_of_run_folders_records_the_run_folder_and_part(
    tmp_path: Path, results: Path
) -> None:
    """--dut under a results folder: the newest run folder of the part is used and said so;
    results go next to it (not inside it, not shared with other parts); JSON and PDF name
    the run folder and the part; --export-csv writes the loaded data, then analyses."""
    newest = results / "20260103T090000Z_SIM-0001"
    before = sorted(p.name for p in newest.iterdir())
    export = tmp_path / "part.csv"
    out = _station(str(results), "--dut", "SIM-0001", "--export-csv", str(export))
    assert out.returncode == 0, out.stderr
    dest = results / "20260103T090000Z_SIM-0001_discrepancy"
    assert sorted(p.name for p in newest.iterdir()) == before  # the record is untouched
    assert {"discrepancy.json", "model.yaml", "discrepancy_report.pdf"} <= {
        p.name for p in dest.iterdir()}
    assert not (results / "discrepancy").exists()
    note = "3 run folders for SIM-0001; the newest, 20260103T090000Z_SIM-0001, was used"
    assert f"out: {dest}" in out.stdout
    assert note in out.stdout
    # the loader's notes are on the console too, not only in the PDF/JSON
    assert "note: no latched encoder counts (hardware sync)" in out.stdout
    data = json.loads((dest / "discrepancy.json").read_text())
    assert set(data) >= PINNED
    assert data["serial"] == "SIM-0001"
    assert data["run_folder"] == data["source"] == str(newest.resolve())
    assert data["data"] == str(results)
    assert data["notes"][0] == note
    assert data["exported_csv"] == str(export)
    text = _pdf_text((dest / "discrepancy_report.pdf").read_bytes())
    assert _pdf_line(text, "Data:") == f"Data: {newest.resolve()} (part SIM-0001)"
    assert _pdf_line(text, "Note: 3 run folders") == f"Note: {note}"
    # the export: pinned columns plus segment_kind, the samples the analysis used
    header = export.read_text().splitlines()[0].split(",")
    assert header == [*CSV_COLUMNS, "segment_kind"]
    back, loaded = load_csv(export), load_data(newest)
    assert back.n == loaded.n
    assert np.allclose(back.gyro_dps, loaded.gyro_dps, rtol=1e-8)
    assert {s.kind for s in back.segments} == {s.kind for s in loaded.segments}


def test_find_run_folder_says_how_many_it_chose_from(results: Path) -> None:
    choice = find_run_folder(results, "SIM-0001")
    assert choice.folder.name == "20260103T090000Z_SIM-0001" and choice.candidates == 3
    assert choice.note == (
        "3 run folders for SIM-0001; the newest, 20260103T090000Z_SIM-0001, was used")
    one = find_run_folder(results, "SIM-0002")
    assert one.candidates == 1 and one.note is None
    itself = find_run_folder(results / "20260101T120000Z_SIM-0001", "SIM-0001")
    assert itself.folder.name == "20260101T120000Z_SIM-0001" and itself.note is None


def test_two_csvs_in_one_folder_keep_their_own_results_and_json_to_stdout(
    tmp_path: Path, tiny_run: dict[str, object]
) -> None:
    folder = tmp_path / "R&D <b>"  # markup characters in the path: the PDF's Data line
    folder.mkdir()
    traj = as_trajectory(tiny_run)
    write_csv(folder / "a.csv", traj)
    write_csv(folder / "b.csv", traj)
    out_a = _station(str(folder / "a.csv"), cwd=tmp_path)
    assert out_a.returncode == 0, out_a.stderr
    a_json = folder / "a_discrepancy" / "discrepancy.json"
    first = a_json.read_text()
    assert f"out: {folder / 'a_discrepancy'}" in out_a.stdout
    assert json.loads(first)["serial"] is None and json.loads(first)["run_folder"] is None
    assert "report_error" not in json.loads(first)
    text = _pdf_text((folder / "a_discrepancy" / "discrepancy_report.pdf").read_bytes())
    assert _pdf_line(text, "Data:") == f"Data: {(folder / 'a.csv').resolve()}"
    # --json -: the JSON alone on stdout, the summary on stderr, no file named "-"
    out_b = _station(str(folder / "b.csv"), "--json", "-", cwd=tmp_path)
    assert out_b.returncode == 0, out_b.stderr
    data = json.loads(out_b.stdout)
    assert set(data) >= PINNED
    assert data["source"] == str((folder / "b.csv").resolve())
    assert "json: stdout" in out_b.stderr and "gap" in out_b.stderr
    assert not (tmp_path / "-").exists()
    assert (folder / "b_discrepancy" / "model.yaml").exists()
    assert not (folder / "b_discrepancy" / "discrepancy.json").exists()
    assert a_json.read_text() == first  # a's results were not overwritten
    assert not (folder / "discrepancy").exists()


def _fail_if_loaded(*_args: object, **_kwargs: object) -> None:
    raise AssertionError("the data were loaded before the paths were checked")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--out", "{tmp}/afile"], "is a file"),
        (["--out", "/proc/forbidden"], "cannot create or write there"),
        (["--json", "{tmp}"], "is a folder"),
        (["--json", "{tmp}/nonexistent_dir/a.json"], "does not exist"),
        (["--json", "/proc/a.json"], "cannot write there"),
        (["--export-csv", "{tmp}/nonexistent_dir/x.csv"], "does not exist"),
        (["--export-csv", "{tmp}/in.csv"], "is the input data"),
        (["--json", "{tmp}/in.csv"], "is the input data"),
    ],
)
def test_bad_output_paths_fail_before_the_data_are_loaded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    extra: list[str], message: str
) -> None:
    (tmp_path / "in.csv").write_text(",".join(CSV_COLUMNS) + "\n")
    (tmp_path / "afile").write_text("x")
    monkeypatch.setattr("procedures.model.run_folder.load_data", _fail_if_loaded)
    monkeypatch.setattr("procedures.model.discrepancy.run_discrepancy", _fail_if_loaded)
    args = [a.replace("{tmp}", str(tmp_path)) for a in extra]
    assert cli.main(["discrepancy", str(tmp_path / "in.csv"), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert not (tmp_path / "nonexistent_dir").exists()  # parents of --json are not made
    assert not Path("/proc/forbidden").exists()
    assert not (tmp_path / "in_discrepancy").exists()  # no empty result folder left behind
    assert (tmp_path / "afile").read_text() == "x"


def test_an_os_error_while_writing_results_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    tiny_run: dict[str, object]
) -> None:
    csv_path = write_csv(tmp_path / "run.csv", as_trajectory(tiny_run))

    def full_disk(*_args: object, **_kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("procedures.model.model_io.save_model", full_disk)
    assert cli.main(["discrepancy", str(csv_path)]) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and len(err.strip().splitlines()) == 1, err


def test_console_says_not_identifiable_not_separable_and_the_notes(
    capsys: pytest.CaptureFixture[str]
) -> None:
    reason = "each explains the gap about equally well; none was added"
    result = SimpleNamespace(
        notes=("40 samples left out: compensated, clipped, over range, temperature invalid "
               "or supply low",),
        gap_initial_dps=0.5, noise_floor_dps=0.01, gap_final_dps=0.5, iterations=[],
        not_separable=({"effects": ["k2_quadratic", "scale_asymmetry"], "reason": reason},),
        not_identifiable=("g_sensitivity_tilt", "warmup_drift"),
        unexplained_remains=True,
        unexplained_message="unexplained structure remains: the gap is 50.00 x the noise "
                            "floor after the named effects; the residual pattern is strongest "
                            "against temperature_rate (F 300, p 1e-30)",
    )
    cli_discrepancy._print_summary(result, Path("o"), Path("o/d.json"),  # type: ignore[arg-type]
                                   Path("o/model.yaml"), None, sys.stdout)
    lines = capsys.readouterr().out.splitlines()
    assert "note: 40 samples left out: compensated, clipped, over range, temperature " \
           "invalid or supply low" in lines
    assert f"not separable: k2_quadratic / scale_asymmetry: {reason}" in lines
    ni = [ln for ln in lines if ln.startswith("not identifiable:")]
    assert len(ni) == 1 and "g_sensitivity_tilt, warmup_drift" in ni[0]
    assert "no independent signature" in ni[0]
    assert "out: o" in lines
    warn = [ln for ln in lines if ln.startswith("WARNING: unexplained structure remains")]
    assert len(warn) == 1 and "against temperature_rate" in warn[0]


def test_console_says_when_the_main_effect_was_named_before_its_look_alike(
    capsys: pytest.CaptureFixture[str]
) -> None:
    named = SimpleNamespace(
        effect="lib_dTdt", gap_before_dps=0.02, gap_after_dps=0.01,
        evidence={"p_holm": 1e-9, "preferred_over": ["lib_dTdt_dV"],
                  "rule": "marginality: of look-alikes, the main effect is named"},
        formula="bias proportional to d(die temperature)/dt: 0.5 deg/s per (C/s)",
        regressors=("temperature_rate",),
    )
    result = SimpleNamespace(
        notes=(), gap_initial_dps=0.02, noise_floor_dps=0.01, gap_final_dps=0.01,
        iterations=[named], not_separable=(), not_identifiable=(),
        unexplained_remains=False, unexplained_message="",
    )
    cli_discrepancy._print_summary(result, Path("o"), Path("o/d.json"),  # type: ignore[arg-type]
                                   Path("o/model.yaml"), None, sys.stdout)
    lines = capsys.readouterr().out.splitlines()
    assert ("  named before its look-alike interaction(s) lib_dTdt_dV: the main effect "
            "(marginality)") in lines
    assert not any(ln.startswith("not separable") for ln in lines)


def test_help_names_every_input_and_the_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["discrepancy", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "run folder (record.json + raw.h5), folder of run folders (with --dut), or CSV" in text
    assert "default OUT/discrepancy.json" in text and "'-' prints it to stdout" in text
    assert "<folder of the CSV>/<CSV name without .csv>_discrepancy for a CSV" in text
    assert "<folder holding the run folder>/<run folder name>_discrepancy for a run folder" \
        in text
    assert "--export-csv PATH" in text and "segment_kind" in text


def test_docs_describe_the_cli_and_refer_only_to_files_in_the_repository() -> None:
    doc = (ROOT / "docs" / "discrepancy.md").read_text()
    assert "DESIGN.md" not in doc
    for path in set(re.findall(r"\b[\w./-]+/[\w.-]+\.(?:py|yaml|md)\b", doc)):
        found = list(ROOT.glob(path)) if "*" in path else [ROOT / path]
        assert found and all(p.exists() for p in found), path
    for needle in ("--export-csv", "--json -", "_discrepancy/", "the newest usable one is used",
                   "supply low", "the record's first sample"):
        assert needle in doc, needle


def test_notes_count_samples_in_the_singular_and_include_the_first_sample(
    tmp_path: Path, tiny_run: dict[str, object]
) -> None:
    folder = write_run_folder(tmp_path / "run", tiny_run, latched_counts_per_rev=1 << 20)
    with h5py.File(folder / "raw.h5", "a") as f:
        status = f["samples/status"][()]
        status[2000] |= 1 << 1  # SATURATED: one sample clipped
        f["samples/status"][...] = status
    notes = load_data(folder).notes
    assert any(n.startswith("1 sample left out: compensated, clipped") for n in notes), notes
    # no lost frame: only the record's first sample has no previous latch
    assert any("; 1 sample without a previous latch left out" in n for n in notes), notes
    assert not any(re.search(r"\b1 samples\b", n) for n in notes), notes


@pytest.mark.parametrize("n_steps", range(0, 13))
def test_step_chart_ticks_are_whole_steps(n_steps: int) -> None:
    lo, hi = step_axis_range(n_steps)
    assert lo < 0 and hi > n_steps
    ticks = nice_ticks(lo, hi)
    assert 0.0 in ticks and all(float(t).is_integer() for t in ticks), ticks
