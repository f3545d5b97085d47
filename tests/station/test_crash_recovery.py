"""Crash recovery: which step a crashed run names, and every entry point that opens results.

The end-to-end case (kill -9 of `station ui` mid-run on the simulated bench, then a new start)
is tests/ui/test_ui_crash.py; `station run` killed mid-run is in test_run_cli.py.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from procedures.runtime.record import (
    Dut,
    Event,
    FileRef,
    RunRecord,
    Verdict,
    read_record,
    write_record,
)
from station.run_folder import (
    LOCK_FILE,
    create_run_folder,
    last_completed_step,
    recover_crashed_runs,
    recover_results,
)


def _dead_pid() -> int:
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    return int(done.stdout)


def _crashed(out: Path, serial: str, timings: dict[str, float], last_event_step: str) -> Path:
    """A run folder as a station killed mid-run leaves it: RUNNING, its lock naming a dead pid."""
    folder = create_run_folder(out, serial)
    ref = FileRef(path="p", name="GYR-130", sha256="0" * 64)
    record = RunRecord(
        run_id=folder.name,
        verdict=Verdict.RUNNING,
        started_utc="2026-11-23T10:00:00+00:00",
        dut=Dut(serial=serial, socket=1),
        product=ref,
        procedure=ref,
        timings=timings,
        events=[
            Event(time_utc="t", station_time_s=1.0, step=last_event_step, message="started"),
        ],
    )
    write_record(folder, record)
    lock = json.loads((folder / LOCK_FILE).read_text())
    lock["pid"] = _dead_pid()
    (folder / LOCK_FILE).write_text(json.dumps(lock))
    return folder


def test_the_last_completed_step_is_named_not_the_running_one(tmp_path: Path) -> None:
    timings = {"power": 3.0, "thermal[T25 V5.0]": 40.0, "bias[T25 V5.0]": 10.0}
    folder = _crashed(tmp_path, "SIM-0001", timings, "rate_table")
    assert recover_crashed_runs(tmp_path) == [folder]
    rec = read_record(folder)
    assert rec.verdict is Verdict.ERROR
    assert "after step 'bias[T25 V5.0]' completed" in rec.reason
    assert "(last event from 'rate_table')" in rec.reason
    assert rec.events[-1].step == "recovery" and rec.events[-1].level == "ERROR"
    assert last_completed_step(rec) == "bias[T25 V5.0]"  # the recovery did not add a step


def test_a_run_killed_before_any_step_ended_says_so(tmp_path: Path) -> None:
    folder = _crashed(tmp_path, "SIM-0002", {}, "power")
    recover_crashed_runs(tmp_path)
    assert "before any step completed" in read_record(folder).reason


def test_recovery_indexes_the_crashed_run_for_history(tmp_path: Path) -> None:
    from station.results_db import ResultsDB

    out, db_path = tmp_path / "runs", tmp_path / "results.sqlite"
    folder = _crashed(out, "SIM-0003", {"power": 2.0}, "thermal")
    assert recover_results(out, db_path, locks_only=True) == [folder]
    runs = ResultsDB(db_path).runs()
    assert [(r.serial, r.verdict) for r in runs] == [("SIM-0003", "ERROR")]
    assert "after step 'power' completed" in runs[0].reason
    assert recover_results(out, db_path) == []  # once only


def test_the_review_screen_recovers_a_crashed_run_by_itself(tmp_path: Path) -> None:
    """A station that died while another process serves the review: the review's next
    refresh shows the run ERROR with its step, without waiting for a new run to start."""
    from station.ui.history import History, RunFilter

    out = tmp_path / "runs"
    history = History(out, tmp_path / "results.sqlite")
    assert history.query(RunFilter())[1] == []
    folder = _crashed(out, "SIM-0004", {"power": 2.0, "thermal": 30.0}, "bias")
    history._recovered_at = -1e9  # the next query is due to look again
    _, rows = history.query(RunFilter())
    assert [(r["serial"], r["verdict"]) for r in rows] == [("SIM-0004", "ERROR")]
    assert "after step 'thermal' completed" in rows[0]["reason"]
    assert read_record(folder).verdict is Verdict.ERROR


def test_a_live_run_is_left_alone(tmp_path: Path) -> None:
    folder = create_run_folder(tmp_path, "SIM-0005")  # our own pid: running
    ref = FileRef(path="p", sha256="0" * 64)
    write_record(
        folder,
        RunRecord(
            run_id="r", verdict=Verdict.RUNNING, started_utc="2026-11-23T10:00:00+00:00",
            dut=Dut(serial="SIM-0005"), product=ref, procedure=ref,
        ),
    )  # fmt: skip
    assert recover_crashed_runs(tmp_path, locks_only=True) == []
    assert read_record(folder).verdict is Verdict.RUNNING


def test_station_history_lists_a_crashed_run_as_error(tmp_path: Path) -> None:
    import os

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "runs"
    folder = _crashed(out, "SIM-0006", {"power": 2.0, "bias": 9.0}, "rate_table")
    done = subprocess.run(
        [sys.executable, "-m", "station", "history", "--reindex", str(out),
         "--db", str(tmp_path / "r.sqlite"), "--json"],
        capture_output=True, text=True, timeout=120, cwd=root,
        env=dict(os.environ, PYTHONPATH=str(root)),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert f"marked as ERROR (the station stopped during that run): {folder}" in done.stderr
    rows = json.loads(done.stdout)
    assert [(r["serial"], r["verdict"]) for r in rows] == [("SIM-0006", "ERROR")]
    assert "after step 'bias' completed" in rows[0]["reason"]


def test_a_recovered_run_is_numbered_and_sealed(tmp_path: Path) -> None:
    """The station recovers a crashed run as it finishes any other: a certificate number and
    a manifest that `station verify` accepts; a later edit shows as altered."""
    from station.manifest import Status, verify_folder
    from station.station_file import load_settings
    from station.uut import UutRunner
    from tests.reports.test_signing import station_file

    settings = load_settings(station_file(tmp_path / "station"))  # its own key and counter
    out = tmp_path / "runs"
    folder = _crashed(out, "SIM-0009", {"power": 3.0}, "thermal")
    assert verify_folder(folder).status is Status.ALTERED  # no manifest yet
    runner = UutRunner(settings, out=out, operator="pytest")
    assert runner.recover() == [folder]
    rec = read_record(folder)
    assert rec.verdict is Verdict.ERROR and rec.certificate_number.endswith("-000001")
    assert verify_folder(folder).status is Status.INTACT
    (folder / "record.json").write_text((folder / "record.json").read_text() + " ")
    assert verify_folder(folder).status is Status.ALTERED
