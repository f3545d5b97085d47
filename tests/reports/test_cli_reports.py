"""`station report`, `station history`, `station lot-report` through the real CLI."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from station.cli.main import main
from station.pdf_signing import unsigned_revision
from tests.reports.conftest import pdf_text
from tests.reports.lot_data import make_lot

REPO = Path(__file__).resolve().parents[2]


def station_process(*args: str) -> subprocess.CompletedProcess[str]:
    """The real console entry point in its own process."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "station", *args], capture_output=True,
                          text=True, env=env, cwd=REPO, timeout=120)


def station(*args: str) -> subprocess.CompletedProcess[str]:
    """The same CLI in this process (fast); same exit codes and output streams."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


def test_report_twice_gives_identical_bytes(pass_run: Path, tmp_path: Path) -> None:
    folder = tmp_path / pass_run.name
    shutil.copytree(pass_run, folder)
    (folder / "certificate.pdf").unlink()
    first = station_process("report", str(folder))
    assert first.returncode == 0, first.stderr
    assert first.stdout.strip() == str(folder / "certificate.pdf")
    # byte-identity is of the rendered document, before the signatures appended to it
    one = unsigned_revision((folder / "certificate.pdf").read_bytes())
    second = station_process("report", str(folder))
    assert second.returncode == 0
    assert unsigned_revision((folder / "certificate.pdf").read_bytes()) == one
    assert one == (pass_run / "certificate.pdf").read_bytes()  # same as the engine's render


def test_report_on_a_folder_that_is_no_run_folder_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "20261121T000000Z_EMPTY"
    folder.mkdir()
    (folder / "notes.txt").write_text("not a run", encoding="utf-8")
    out = station_process("report", str(folder))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.count("\n") == 1 and "not a run folder" in out.stderr
    assert not (folder / "certificate.pdf").exists()


@pytest.mark.parametrize("lost", ["record.json", "raw.h5"])
def test_report_on_a_run_folder_missing_a_file_writes_error_certificate(
        pass_run: Path, tmp_path: Path, lost: str) -> None:
    folder = tmp_path / pass_run.name
    shutil.copytree(pass_run, folder)
    (folder / lost).unlink()
    (folder / "certificate.pdf").unlink()
    out = station("report", str(folder))
    assert out.returncode == 0 and "Traceback" not in out.stderr
    assert (folder / "certificate.pdf").read_bytes().startswith(b"%PDF")
    assert "ERROR" in pdf_text(folder / "certificate.pdf", page=1)


def test_report_on_no_folder_is_one_clear_line(tmp_path: Path) -> None:
    out = station_process("report", str(tmp_path / "nope"))
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "not a run folder" in out.stderr


def test_report_index_adds_the_run_to_the_database(pass_run: Path, tmp_path: Path) -> None:
    db = tmp_path / "r.sqlite"
    folder = tmp_path / pass_run.name
    shutil.copytree(pass_run, folder)
    assert station("report", str(folder), "--index", "--db", str(db)).returncode == 0
    runs = json.loads(station("history", "--db", str(db), "--json").stdout)
    assert [r["serial"] for r in runs] == ["SIM-PASS-1"]
    assert runs[0]["folder"] == str(folder.resolve())


def test_history_filters_and_summarises(tmp_path: Path) -> None:
    db = tmp_path / "r.sqlite"
    records = make_lot(db, 12)
    out = station("history", "--db", str(db), "--verdict", "fail")
    assert out.returncode == 0, out.stderr
    n_fail = sum(r.verdict.value == "FAIL" for r in records)
    rows = [ln for ln in out.stdout.splitlines() if ln.startswith("2026-")]
    assert len(rows) == n_fail > 0 and all(" FAIL " in ln for ln in rows)
    assert f"{n_fail} run{'s' if n_fail > 1 else ''}: FAIL {n_fail}" in out.stdout  # "1 run"
    # a list filtered by verdict has no yield of its own (it read "yield 0.0 %")
    assert "yield 0.0 %" not in out.stdout and "no yield (only FAIL runs listed" in out.stdout
    whole = station("history", "--db", str(db)).stdout
    n_pass = sum(r.verdict.value == "PASS" for r in records)
    assert f"yield {n_pass / (n_pass + n_fail) * 100:.1f} %" in whole
    js = json.loads(station("history", "--db", str(db), "--since", "2026-11-21T12:00Z",
                            "--json").stdout)
    assert len(js) == sum(r.started_utc >= "2026-11-21T12:00" for r in records)
    bad = station("history", "--db", str(db), "--since", "yesterday")
    assert bad.returncode == 2 and "YYYY-MM-DD" in bad.stderr


def test_history_without_database_says_how_to_fix(tmp_path: Path) -> None:
    out = station("history", "--db", str(tmp_path / "missing.sqlite"))
    assert out.returncode == 2 and "--db PATH" in out.stderr
    assert not (tmp_path / "missing.sqlite").exists()  # not created by a read


def test_lot_report_writes_pdf_and_prints_yield(tmp_path: Path) -> None:
    db = tmp_path / "r.sqlite"
    records = make_lot(db, 20)
    out_pdf = tmp_path / "lot.pdf"
    out = station("lot-report", "--db", str(db), "--product", "ADIS16130-EOL",
                  "--out", str(out_pdf))
    assert out.returncode == 0, out.stderr
    passed = sum(r.verdict.value == "PASS" for r in records)
    done = sum(r.verdict.value in ("PASS", "FAIL") for r in records)
    assert f"yield {passed / done * 100:.1f} %" in out.stdout
    assert out_pdf.read_bytes().startswith(b"%PDF")
    bad = station("lot-report", "--db", str(db), "--out", str(tmp_path / "lot.txt"))
    assert bad.returncode == 2 and ".pdf" in bad.stderr
    # --issued reproduces a report byte for byte
    again = [tmp_path / "again1.pdf", tmp_path / "again2.pdf"]
    for pdf in again:
        ok = station("lot-report", "--db", str(db), "--issued", "2026-12-01T08:15:00Z",
                     "--out", str(pdf))
        assert ok.returncode == 0, ok.stderr
    assert again[0].read_bytes() == again[1].read_bytes()
    assert b"D:20261201081500+00'00'" in again[0].read_bytes()
    bad = station("lot-report", "--db", str(db), "--issued", "last tuesday",
                  "--out", str(out_pdf))
    assert bad.returncode == 2 and "--issued" in bad.stderr


def test_history_reindex_rebuilds_the_database_from_run_folders(
        pass_run: Path, fail_run: Path, tmp_path: Path) -> None:
    root = tmp_path / "runs"
    for f in (pass_run, fail_run):
        shutil.copytree(f, root / f.name)
    broken = root / "20261121T120000Z_BROKEN"
    broken.mkdir()
    (broken / "record.json").write_text("{", encoding="utf-8")
    db = tmp_path / "new.sqlite"
    out = station("history", "--db", str(db), "--reindex", str(root), "--json")
    assert out.returncode == 0, out.stderr
    assert sorted(r["serial"] for r in json.loads(out.stdout)) == ["SIM-FAIL-2", "SIM-PASS-1"]
    assert "indexed 2 run folders" in out.stderr and "skipped:" in out.stderr
    assert "BROKEN" in out.stderr


def test_history_columns_fit_long_values(tmp_path: Path) -> None:
    db = tmp_path / "r.sqlite"
    product = "GYR-130 yaw-rate gyroscope"  # longer than the old fixed 18-character column
    records = make_lot(db, 4, product=product)
    out = station("history", "--db", str(db))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    header, rows = lines[0], [ln for ln in lines if ln.startswith("2026-")]
    assert len(rows) == len(records)
    verdict_col = header.index("verdict")
    for ln in rows:
        cells = [c for c in ln.split("  ") if c]
        assert cells[2].strip() == product and cells[3].strip() in ("PASS", "FAIL"), ln
        assert ln[verdict_col:].split()[0] in ("PASS", "FAIL"), ln  # aligned under its header
        assert f"{product} " in ln and f"{product}PASS" not in ln and f"{product}FAIL" not in ln
    assert {ln.split()[1] for ln in rows} == {r.dut.serial for r in records}
