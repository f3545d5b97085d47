"""Small pieces of the UI without a server: password hashes, events, history, CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from station.ui.auth import check_hash_format, hash_password, verify_password
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


def test_sessions_expire_close_and_renew() -> None:
    from station.ui.sessions import Sessions

    sessions = Sessions(lifetime_s=3600)
    session = sessions.open("127.0.0.1")
    assert sessions.get(session.token) is session and sessions.get("forged") is None
    session.operator = "ana"
    fresh = sessions.renew(session)
    assert sessions.get(session.token) is None  # the token seen before sign-in is void
    assert fresh.operator == "ana" and fresh.csrf != session.csrf
    sessions.close(fresh.token)
    assert sessions.get(fresh.token) is None
    expired = Sessions(lifetime_s=-1)
    assert expired.get(expired.open("127.0.0.1").token) is None
    capped = Sessions(max_sessions=3)
    signed = capped.open("a")
    signed.operator = "ana"
    first = capped.open("b")
    for _ in range(3):
        capped.open("c")
    assert capped.get(first.token) is None  # bounded: the oldest unsigned went...
    assert capped.get(signed.token) is signed  # ...not the one an operator signed in on


def test_an_address_cannot_flood_new_sessions() -> None:
    from station.ui.sessions import Sessions, TooManySessions

    sessions = Sessions(per_minute=5)
    kept = [sessions.open("10.0.0.66") for _ in range(5)]
    with pytest.raises(TooManySessions):
        sessions.open("10.0.0.66")
    assert sessions.open("10.0.0.9") is not None  # another address is not affected
    assert sessions.renew(kept[0]) is not None  # renewals are not new sessions


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


def test_cli_hash_pin_and_badge_print_working_operator_entries() -> None:
    from station.ui.auth import Operator, OperatorBook

    pin = _station("--hash-pin", stdin="4711\n")
    badge = _station("--hash-badge", stdin="0004455667\n")
    assert pin.returncode == 0 and badge.returncode == 0, pin.stderr + badge.stderr
    pin_hash = next(x for x in pin.stdout.splitlines() if "pin_hash" in x).split(":", 1)[1]
    badge_hash = next(x for x in badge.stdout.splitlines() if "badge_hash" in x).split(":", 1)[1]
    book = OperatorBook((Operator("Ana", pin_hash.strip(" '"), badge_hash.strip(" '")),))
    book.check()
    assert "4711" not in pin.stdout.replace(pin_hash.strip(" '"), "")  # only its hash
    assert "0004455667" not in badge.stdout
    assert book.by_pin("ana", "4711") is not None and book.by_pin("Ana", "4712") is None
    assert book.by_pin("Bob", "4711") is None
    assert book.by_badge("0004455667") is not None and book.by_badge("0004455668") is None
    short = _station("--hash-pin", stdin="12\n")
    assert short.returncode == 2 and "at least 4" in short.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [(("--port", "99999"), "--port must be"), (("--sim-config", "x.yaml"), "needs --sim")],
)
def test_cli_bad_options_exit_2_with_one_line(args: tuple[str, ...], message: str) -> None:
    out = _station(*args)
    assert out.returncode == 2
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_login_throttle_backs_off_per_client() -> None:
    from station.ui.sessions import LoginThrottle

    throttle = LoginThrottle(free=2, base_s=10, max_s=35)
    assert throttle.failed("a") == 0 and throttle.failed("a") == 0
    assert 9 < throttle.failed("a") <= 10  # third failure: locked
    assert 19 < throttle.failed("a") <= 20  # doubles
    assert 34 < throttle.failed("a") <= 35  # capped
    assert throttle.wait_s("b") == 0  # another client is not locked out
    throttle.reset("a")
    assert throttle.wait_s("a") == 0


def test_review_reads_the_results_database_when_there_is_one(tmp_path: Path) -> None:
    """Same answers from the database index as from the run folders themselves."""
    from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, write_record
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
