"""A station that dies by kill -9 leaves the bench as it was (table turning, supply on, chamber
away from its handling temperature, fixtures streaming); the next `station run` on that same
bench recovers the crashed run and makes the bench safe before its first step, then PASSes.
Two `station run` processes on one bench: the second is refused in one line and touches no
instrument; the first PASSes.

The bench runs as its own process (`station bench --state FILE --lockstep`), so it outlives
the station and its truth can be read; the station runs as a real `station run --sim-bench
FILE` process, watched by tests/station/run_hooked.py: it freezes the run mid-step (in
lockstep the bench's world then stands still exactly there) for the kill, and reads the
bench's truth when `power_identify` begins in the new run.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.sim.control_client import ControlClient
from procedures.record import Verdict, read_record
from station.manifest import Status, verify_folder

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"
HOOK = Path(__file__).with_name("run_hooked.py")
SERIAL = "SIM-0001"
SAFE_TEMP_C = 25.0  # short.yaml's chamber.safe_temp_c

# (step, station s into it when the run is frozen and killed; '' = program: after its first
# calibration write, the step takes no station time)
KILL_POINTS = {
    "power_identify": "1.0",  # supply on, settling
    "thermal": "10",  # chamber running to its condition, streams on
    "bias": "5",
    "rate_table": "15",  # the table at a plateau
    "stop_method": "6",
    "program": "",
    "verify": "3",  # the table turning again
}
TABLE_TURNING = ("rate_table", "verify")


def _env(tmp_path: Path) -> dict[str, str]:
    # every station process of a test shares one lock folder, as on one machine
    return dict(os.environ, PYTHONPATH=str(ROOT), STATION_LOCK_DIR=str(tmp_path / "locks"))


@contextlib.contextmanager
def bench_process(tmp_path: Path) -> Iterator[Path]:
    """`station bench --lockstep` with one good part; yields its state file."""
    sim = tmp_path / "sim.yaml"
    sim.write_text(f"parts:\n  - {{socket: 1, serial: {SERIAL}}}\n", encoding="utf-8")
    state = tmp_path / "bench.json"
    log = (tmp_path / "bench.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "station", "bench", "--state", str(state), "--lockstep",
         "--config", str(sim)],
        cwd=ROOT, env=_env(tmp_path), stdout=log, stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 60
        while not state.exists():
            assert proc.poll() is None, (tmp_path / "bench.log").read_text()
            assert time.monotonic() < deadline, "the bench wrote no state file"
            time.sleep(0.05)
        yield state
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        log.close()


def truth(state: Path) -> dict[str, Any]:
    with ControlClient(json.loads(state.read_text())["control"]) as control:
        return control.truth()


def station_run(
    tmp_path: Path, state: Path, out: Path, marks: Path, *hooks: str
) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(HOOK), str(marks), *hooks, "--", "run", "--sim-bench", str(state),
         "--dut", SERIAL, "--procedure", str(SHORT), "--out", str(out)],
        cwd=ROOT, env=_env(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
    )


def wait_mark(marks: Path, key: str, proc: subprocess.Popen[str], timeout_s: float = 90) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if marks.exists():
            for line in marks.read_text().splitlines():
                entry = json.loads(line)
                if key in entry:
                    return entry
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the run ended (exit {proc.returncode}) before {key!r}:\n{out}\n{err}")
        time.sleep(0.02)
    proc.kill()
    pytest.fail(f"no {key!r} mark within {timeout_s} s")


def finish(proc: subprocess.Popen[str], timeout_s: float = 180) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the run did not end within {timeout_s} s:\n{out}\n{err}")
    return proc.returncode, out, err


def _cells() -> list[Any]:
    # one representative cell in the default run (the finding: the table still turning at
    # 200 deg/s and the fixture streaming); the others in the station grid
    return [
        pytest.param(step, marks=() if step == "rate_table" else pytest.mark.station_grid)
        for step in KILL_POINTS
    ]


@pytest.mark.parametrize("step", _cells())
def test_kill9_mid_step_then_the_next_run_starts_safe_and_passes(
    tmp_path: Path, step: str
) -> None:
    out = tmp_path / "out"
    with bench_process(tmp_path) as state:
        crashed = station_run(
            tmp_path, state, out, tmp_path / "crashed.jsonl",
            "--freeze-at", f"{step}:{KILL_POINTS[step]}",
        )
        frozen = wait_mark(tmp_path / "crashed.jsonl", "frozen", crashed)
        assert frozen["frozen"] == step
        crashed.kill()  # SIGKILL: no handler, no safe state, no record written
        crashed.communicate(timeout=10)
        assert crashed.returncode == -9
        found = truth(state)
        # the bench as the dead station left it: not safe (else the cell proves nothing)
        assert found["supply"]["output"] is True, found["supply"]
        if step != "power_identify":
            assert found["sockets"]["1"]["stream_enabled"] is True
        if step in TABLE_TURNING:
            assert found["table"]["enabled"] and abs(found["table"]["rate_dps"]) > 1.0
        (crashed_folder,) = list(out.glob(f"*_{SERIAL}"))
        assert read_record(crashed_folder).verdict is Verdict.RUNNING

        marks = tmp_path / "new.jsonl"
        code, stdout, stderr = finish(
            station_run(tmp_path, state, out, marks, "--truth-at", "power_identify")
        )
        at_power = next(
            json.loads(line)["truth"] for line in marks.read_text().splitlines()
            if "truth" in json.loads(line)
        )

    assert code == 0, stdout + stderr
    assert f"socket 1 {SERIAL}: PASS" in stdout
    # the bench's own truth when the new run's power_identify began: safe, streams stopped
    assert at_power["safe"]["all"], at_power["safe"]
    assert at_power["table"]["enabled"] is False and abs(at_power["table"]["rate_dps"]) < 1e-6
    assert at_power["supply"]["output"] is False
    assert at_power["chamber"]["setpoint_c"] == pytest.approx(SAFE_TEMP_C)
    assert not any(s["stream_enabled"] for s in at_power["sockets"].values())
    # the crashed run: recovered (ERROR, naming the crash), sealed, no lock left
    crashed_record = read_record(crashed_folder)
    assert crashed_record.verdict is Verdict.ERROR
    assert "stopped during the run" in crashed_record.reason
    assert not (crashed_folder / ".running").exists()
    assert verify_folder(crashed_folder).status is Status.INTACT
    # the new run says what it found and read back before its first step
    (new_folder,) = [f for f in out.glob(f"*_{SERIAL}") if f != crashed_folder]
    start = read_record(new_folder).analysis["start_safe_state"]
    assert start["all_safe"], start
    assert "STREAM? 0" in start["instruments"]["streams"]["detail"]


def test_two_station_runs_on_one_bench_the_second_is_refused(tmp_path: Path) -> None:
    out_first, out_second = tmp_path / "first", tmp_path / "second"
    release = tmp_path / "release"
    with bench_process(tmp_path) as state:
        first = station_run(
            tmp_path, state, out_first, tmp_path / "first.jsonl",
            "--freeze-at", "thermal:5", "--until", str(release),
        )
        wait_mark(tmp_path / "first.jsonl", "frozen", first)  # mid-run, holding the bench
        before = truth(state)["modbus"]
        code, stdout, stderr = finish(
            station_run(tmp_path, state, out_second, tmp_path / "second.jsonl"), 60
        )
        after = truth(state)["modbus"]
        release.touch()
        first_code, first_out, first_err = finish(first)

    assert code == 2, stdout + stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    assert "in use by another station process" in lines[0] and f"pid {first.pid}" in lines[0]
    # the second never touched an instrument nor wrote a run
    assert after["table"]["requests"] == before["table"]["requests"]
    assert after["chamber"]["requests"] == before["chamber"]["requests"]
    assert not list(out_second.glob(f"*_{SERIAL}"))
    # the first was unaffected
    assert first_code == 0, first_out + first_err
    (folder,) = list(out_first.glob(f"*_{SERIAL}"))
    record = read_record(folder)
    assert record.verdict is Verdict.PASS
    starts = [e for e in record.events if e.message.startswith("safe before the first step")]
    assert len(starts) == 4  # table, streams, supply, chamber: its own pass, once
