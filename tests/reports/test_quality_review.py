"""The quality engineer's review (issue 26): history and lot report by lot and work order
(finding 5), the socket indexed for the review screen (8), an approval shown on the
certificate and a FAIL run approved only with a remark (9), and `station verify` after
`station report` saying the folder was sealed at the run (10)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from procedures.runtime.record import Verdict
from station.certify import finish_run_folder
from station.results_db import ResultsDB
from station.settings import LoadedSettings
from station.station_file import load_settings
from station.ui.history import History, RunFilter
from tests.reports.conftest import pdf_text
from tests.reports.synth_run import Part, make_record, make_run
from tests.reports.test_signing import station, station_file
from tests.tools import need


@pytest.fixture(scope="module")
def lot_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four runs: LOT-7 / WO-1 twice, LOT-8 / WO-2, and one with neither; sockets 1..4."""
    db_path = tmp_path_factory.mktemp("lotdb") / "results.sqlite"
    db = ResultsDB(db_path)
    for i, (lot, wo) in enumerate([("LOT-7", "WO-1"), ("LOT-7", "WO-1"), ("LOT-8", "WO-2"),
                                   ("", "")]):
        record = make_record(Part(serial=f"SIM-{i + 1:04d}", seed=i + 1))
        record.lot, record.work_order, record.dut.socket = lot, wo, i + 1
        db.add_run(db_path.parent / record.run_id, record)
    return db_path


def test_history_selects_a_lot_and_a_work_order(lot_db: Path) -> None:
    out = station("history", "--lot", "LOT-7", "--db", str(lot_db))
    assert out[0] == 0, out[2]
    assert "SIM-0001" in out[1] and "SIM-0002" in out[1] and "SIM-0003" not in out[1]
    assert "LOT-7" in out[1] and "2 runs:" in out[1]
    out = station("history", "--work-order", "WO-2", "--db", str(lot_db))
    assert out[0] == 0, out[2]
    assert "SIM-0003" in out[1] and "SIM-0001" not in out[1] and "1 run:" in out[1]


def test_lot_report_by_lot_and_by_work_order(lot_db: Path, tmp_path: Path) -> None:
    for flag, value, n in (("--lot", "LOT-7", "2 runs"), ("--work-order", "WO-2", "1 run,")):
        pdf = tmp_path / f"{value}.pdf"
        out = station("lot-report", flag, value, "--db", str(lot_db), "--out", str(pdf),
                      "--include-simulated")  # a simulated bench's runs
        assert out[0] == 0, out[2]
        assert n in out[1]
        text = pdf_text(pdf)
        assert f"{flag.removeprefix('--').replace('-', '_')} = {value}" in text
        assert "deg/sqrt(h)" in text.split()  # units whole in the capability table (finding 14)


def test_socket_is_indexed_and_shown_to_the_review_screen(lot_db: Path) -> None:
    runs = ResultsDB(lot_db).runs()
    assert sorted(r.socket for r in runs) == [1, 2, 3, 4]
    rows = History(lot_db.parent / "no-such-runs", lot_db).rows(RunFilter())
    assert sorted(r["socket"] for r in rows) == [1, 2, 3, 4]


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory) -> LoadedSettings:
    return load_settings(station_file(tmp_path_factory.mktemp("station")))


def _issued(root: Path, settings: LoadedSettings, part: Part) -> Path:
    folder, _ = make_run(root, part)
    assert finish_run_folder(folder, settings, certificate=True) is not None
    return folder


def test_approval_is_visible_on_the_certificate_and_both_signatures_valid(
        tmp_path: Path, settings: LoadedSettings) -> None:
    folder = _issued(tmp_path, settings, Part(serial="SIM-APPR-1", seed=11))
    assert "Q. Engineer" not in pdf_text(folder / "certificate.pdf")
    code, out, err = station("approve", str(folder), "--by", "Q. Engineer",
                             "--station", str(settings.source.path))
    assert code == 0, err
    text = pdf_text(folder / "certificate.pdf")
    box = text[text.index("Reviewed by (quality)"):]
    assert "Q. Engineer (quality)" in box and "Approval-1" in box
    assert "signed digitally" in box
    need("pdfsig")
    sig = subprocess.run(["pdfsig", str(folder / "certificate.pdf")], capture_output=True,
                         text=True).stdout
    assert sig.count("Signature Validation: Signature is Valid.") == 2, sig
    assert station("verify", str(folder), "--station", str(settings.source.path))[0] == 0
    # `station report` renders it again with the approval still in the box
    assert station("report", str(folder), "--station", str(settings.source.path))[0] == 0
    assert "Q. Engineer (quality)" in pdf_text(folder / "certificate.pdf")


def test_a_fail_run_is_approved_only_with_a_remark(
        tmp_path: Path, settings: LoadedSettings) -> None:
    folder = _issued(tmp_path, settings, Part(serial="SIM-FAIL-9", bias_dps=12.5, seed=12))
    from procedures.runtime.record import read_record

    assert read_record(folder).verdict is Verdict.FAIL
    code, _, err = station("approve", str(folder), "--by", "Q. Engineer",
                           "--station", str(settings.source.path))
    assert code == 2 and err.count("\n") == 1 and "--remark" in err
    assert not (folder / "approvals.json").exists()
    code, _, err = station("approve", str(folder), "--by", "Q. Engineer", "--remark",
                           "concession 17: bias limit waived for this lot",
                           "--station", str(settings.source.path))
    assert code == 0, err
    text = " ".join(pdf_text(folder / "certificate.pdf", layout=False).split())
    assert "remark: concession 17: bias limit waived for this lot" in text


@pytest.mark.parametrize("verdict", ["ABORTED", "ERROR"])
def test_a_run_that_did_not_finish_is_approved_only_with_a_remark(
        tmp_path: Path, settings: LoadedSettings, verdict: str) -> None:
    folder = _issued(tmp_path, settings, Part(serial=f"SIM-{verdict}-1", seed=14,
                                              verdict=verdict))
    code, _, err = station("approve", str(folder), "--by", "Q. Engineer",
                           "--station", str(settings.source.path))
    assert code == 2 and err.count("\n") == 1 and f"{verdict} run" in err and "--remark" in err
    assert not (folder / "approvals.json").exists()
    code, _, err = station("approve", str(folder), "--by", "Q. Engineer", "--remark",
                           "part returned to stock", "--station", str(settings.source.path))
    assert code == 0, err


def test_verify_after_report_says_sealed_at_the_run(
        tmp_path: Path, settings: LoadedSettings) -> None:
    folder = _issued(tmp_path, settings, Part(serial="SIM-SEAL-1", seed=13))
    station_arg = ("--station", str(settings.source.path))
    code, out, _ = station("verify", str(folder), *station_arg)
    assert code == 0 and "sealed at the end of the run" in out
    assert station("report", str(folder), *station_arg)[0] == 0
    code, out, _ = station("verify", str(folder), *station_arg)
    assert code == 0, out
    assert "not at the run" not in out
    assert "sealed at the end of the run, sealed again by `station report`" in out
    assert station("approve", str(folder), "--by", "Q", *station_arg)[0] == 0
    code, out, _ = station("verify", str(folder), *station_arg)
    assert "sealed at the end of the run, sealed again after a quality approval" in out
