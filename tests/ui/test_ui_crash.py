"""kill -9 of `station ui` mid-run on the simulated bench, then `station ui` again.

The run the dead station left RUNNING is ERROR as soon as the new station answers (not at
the next Start), its reason names the last step that completed (read from the record as the
killed station left it), and it is on the review screen and in the results database.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import time
from pathlib import Path

import httpx
import pytest

from procedures.runtime.record import Verdict, read_record
from tests.ui.stationkit import (
    PASS_SERIAL,
    make_station_config,
    start_ui_process,
    stop_ui_process,
)

pytestmark = pytest.mark.slow


def _bench_pid(log: Path) -> int | None:
    m = re.search(r"simulated bench running at \S+ \(pid (\d+)\)", log.read_text())
    return int(m.group(1)) if m else None


def _wait_for_completed_steps(runs: Path, n: int, timeout_s: float = 90.0) -> Path:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for path in runs.glob(f"*_{PASS_SERIAL}/record.json"):
            with contextlib.suppress(OSError, ValueError):
                timings = json.loads(path.read_text())["timings"]
                if len(timings) >= n:
                    return path.parent
        time.sleep(0.05)
    raise AssertionError(f"no run completed {n} steps within {timeout_s:g} s")


def test_kill_9_mid_run_then_restart_shows_the_run_as_error(
    tmp_path: Path, page: object
) -> None:
    config = tmp_path / "config"
    make_station_config(config)
    runs = config / "runs"
    first = start_ui_process(config, tmp_path / "ui1.log", speed=50.0)
    bench_pid = _bench_pid(tmp_path / "ui1.log")
    try:
        with first.client() as client:
            r = client.post("/api/signin", json={"name": "ana"})
            client.headers["X-CSRF-Token"] = r.json()["csrf"]
            r = client.post("/api/start", json={"serials": {"1": PASS_SERIAL}})
            assert r.status_code == 200, r.text
        folder = _wait_for_completed_steps(runs, 2)
        first.process.send_signal(signal.SIGKILL)
        first.process.wait(10)
    finally:
        stop_ui_process(first.process)
        if bench_pid:  # its bench dies with it; make sure of it
            with contextlib.suppress(ProcessLookupError):
                os.kill(bench_pid, signal.SIGTERM)
    left = read_record(folder)
    assert left.verdict is Verdict.RUNNING and left.operator == "ana"
    done = [k for k in left.timings if k != "total"]
    assert done, "the killed station had completed steps"
    # A new station start: recovered before it serves anything.
    second = start_ui_process(config, tmp_path / "ui2.log", speed=50.0)
    try:
        rec = read_record(folder)
        assert rec.verdict is Verdict.ERROR
        assert f"after step {done[-1]!r} completed" in rec.reason, rec.reason
        assert "marked as ERROR" in (tmp_path / "ui2.log").read_text()
        runs_api = httpx.get(second.url + "/api/runs", timeout=10).json()
        row = next(r for r in runs_api["runs"] if r["serial"] == PASS_SERIAL)
        assert row["verdict"] == "ERROR" and done[-1] in row["reason"]
        assert row["operator"] == "ana"
        # ...and the review screen shows it.
        page.goto(second.url + "/review")  # type: ignore[attr-defined]
        cells = page.locator("#runs tr").first  # type: ignore[attr-defined]
        from playwright.sync_api import expect

        expect(cells).to_contain_text("ERROR")
        expect(cells).to_contain_text(done[-1])
    finally:
        stop_ui_process(second.process)
