"""Small pieces of the UI without a server: password hashes, events, history, CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from station.ui.auth import Sessions, check_hash_format, hash_password, verify_password
from station.ui.history import RunFilter, yield_summary
from station.ui.hub import format_sse
from station.ui.runner_adapter import _example_serial

REPO = Path(__file__).resolve().parents[2]


def test_password_hash_is_salted_and_verifies() -> None:
    a, b = hash_password("line-eng-42"), hash_password("line-eng-42")
    assert a != b  # salted: the same password never gives the same string
    assert "line-eng-42" not in a
    assert verify_password("line-eng-42", a) and verify_password("line-eng-42", b)
    assert not verify_password("line-eng-43", a)
    with pytest.raises(ValueError, match="at least 6"):
        hash_password("abc")


@pytest.mark.parametrize("bad", ["plaintext", "scrypt$1$2$3$zz$00", "pbkdf2$1$2$3$00$00"])
def test_malformed_hash_says_how_to_fix(bad: str) -> None:
    with pytest.raises(ValueError, match="station ui --hash-password"):
        check_hash_format(bad)


def test_sessions_expire_and_close() -> None:
    sessions = Sessions(lifetime_s=3600)
    token = sessions.open()
    assert sessions.is_engineer(token) and not sessions.is_engineer("forged")
    sessions.close(token)
    assert not sessions.is_engineer(token)
    expired = Sessions(lifetime_s=-1)
    assert not expired.is_engineer(expired.open())


def test_events_never_carry_nan_to_the_page() -> None:
    text = format_sse({"type": "samples", "rate_dps": [1.5, float("nan"), float("inf")]})
    assert text.startswith("data: ") and text.endswith("\n\n")
    assert json.loads(text[6:])["rate_dps"] == [1.5, None, None]


def _row(verdict: str, started: str, serial: str = "SIM-0001") -> dict[str, str]:
    return {
        "serial": serial,
        "verdict": verdict,
        "product": "GYR-130",
        "operator": "ana",
        "started_utc": started,
    }


def test_history_filter_dates_are_inclusive_days() -> None:
    row = _row("PASS", "2026-11-21T23:59:00+00:00")
    assert RunFilter(until="2026-11-21").matches(row)
    assert not RunFilter(until="2026-11-20").matches(row)
    assert RunFilter(since="2026-11-21").matches(row)
    assert not RunFilter(since="2026-11-22").matches(row)
    assert RunFilter(serial="0001", verdict="pass").matches(row)
    assert not RunFilter(serial="0002").matches(row)


def test_yield_counts_completed_parts_only() -> None:
    rows = [_row(v, "2026-11-21") for v in ("PASS", "PASS", "FAIL", "ABORTED", "ERROR")]
    summary = yield_summary(rows)
    assert summary["yield"] == pytest.approx(2 / 3)
    assert summary["completed"] == 3 and summary["total"] == 5
    assert yield_summary([_row("ABORTED", "x")])["yield"] is None


def test_example_serial_fits_its_pattern() -> None:
    import re

    pattern = "^[A-Z]{2,4}-[0-9]{4,8}$"
    assert re.fullmatch(pattern, _example_serial(pattern))
    assert _example_serial("^G2-[0-9]{6}$") == ""  # no guess rather than a wrong one


def _station(*args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(
        [sys.executable, "-m", "station", "ui", *args],
        input=stdin,
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=60,
    )


def test_cli_hash_password_prints_a_working_yaml_line() -> None:
    out = _station("--hash-password", stdin="line-eng-42\n")
    assert out.returncode == 0
    line = next(x for x in out.stdout.splitlines() if "engineer_password_hash" in x)
    stored = line.split(":", 1)[1].strip().strip("'")
    assert verify_password("line-eng-42", stored)


@pytest.mark.parametrize(
    ("args", "message"),
    [(("--port", "99999"), "--port must be"), (("--sim-config", "x.yaml"), "needs --sim")],
)
def test_cli_bad_options_exit_2_with_one_line(args: tuple[str, ...], message: str) -> None:
    out = _station(*args)
    assert out.returncode == 2
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_login_throttle_locks_after_repeated_failures() -> None:
    from station.ui.auth import LoginThrottle

    throttle = LoginThrottle(limit=3, window_s=60, lockout_s=30)
    throttle.failed()
    throttle.failed()
    assert throttle.wait_s() == 0
    throttle.failed()
    assert 29 < throttle.wait_s() <= 30


def test_review_reads_the_results_database_when_there_is_one(tmp_path: Path) -> None:
    """Same answers from the database index as from the run folders themselves."""
    from procedures.record import Dut, FileRef, RunRecord, Verdict, write_record
    from station.results_db import ResultsDB
    from station.ui.history import History

    out = tmp_path / "runs"
    db = ResultsDB(tmp_path / "results.sqlite")
    for i, (verdict, day) in enumerate(
        [(Verdict.PASS, "2026-11-20"), (Verdict.FAIL, "2026-11-21"), (Verdict.PASS, "2026-11-21")]
    ):
        folder = out / f"{day.replace('-', '')}T10000{i}Z_AB-000{i}"
        record = RunRecord(
            run_id=folder.name,
            verdict=verdict,
            started_utc=f"{day}T10:00:0{i}+00:00",
            dut=Dut(serial=f"AB-000{i}"),
            operator="ana",
            product=FileRef(path="p.yaml", name="GYR-130", sha256="0" * 64),
            procedure=FileRef(path="q.yaml", name="eol", sha256="0" * 64),
        )
        write_record(folder, record)
        db.add_run(folder, record)
    (out / "20261121T100001Z_AB-0001" / "certificate.pdf").write_bytes(b"%PDF-1.4")
    by_db = History(out, tmp_path / "results.sqlite")
    by_folder = History(out)
    for flt in (
        RunFilter(),
        RunFilter(until="2026-11-20"),
        RunFilter(since="2026-11-21"),
        RunFilter(verdict="FAIL"),
        RunFilter(serial="0002"),
    ):
        db_summary, db_rows = by_db.query(flt)
        folder_summary, folder_rows = by_folder.query(flt)
        assert [r["serial"] for r in db_rows] == [r["serial"] for r in folder_rows], flt
        assert db_summary == folder_summary
    summary, rows = by_db.query(RunFilter())
    assert summary["yield"] == pytest.approx(2 / 3)
    assert [r["certificate_url"] is not None for r in rows] == [False, True, False]
