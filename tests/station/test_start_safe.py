"""A station that dies by kill -9 leaves the bench as it was (table turning, supply on, chamber
away from its handling temperature, fixtures streaming); the next `station run` on that same
bench recovers the crashed run and makes the bench safe before its first step, then PASSes;
the same in the ramp calibration (the chamber heading for the product's maximum, the table
cycling through the rate set). Two `station run` processes on one bench: the second is
refused in one line and touches no instrument; the first PASSes. How the cells run:
tests/station/crash_cells.py.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from procedures.runtime.record import Verdict, read_record
from station.manifest import Status, verify_folder
from tests.station.crash_cells import (
    KILL_POINTS,
    RAMP_KILL_POINTS,
    RAMP_SHORT,
    SAFE_TEMP_C,
    SERIAL,
    SHORT,
    START_SAFE_EVENT,
    bench_process,
    finish,
    run_crash_cell,
    station_run,
    truth,
    wait_mark,
)

pytestmark = pytest.mark.slow
TABLE_TURNING = ("rate_table", "verify", "ramp_calibration")
CHAMBER_AWAY = ("thermal", "ramp_calibration")  # the setpoint elsewhere than the safe one


def _cells() -> list[Any]:
    # one representative cell in the default run (the finding: the table still turning at
    # 200 deg/s and the fixture streaming); the others in the station grid
    return [
        pytest.param(step, SHORT, marks=() if step == "rate_table" else pytest.mark.station_grid,
                     id=step)
        for step in KILL_POINTS
    ] + [pytest.param(step, RAMP_SHORT, marks=pytest.mark.station_grid, id=step)
         for step in RAMP_KILL_POINTS]


@pytest.mark.parametrize(("step", "procedure"), _cells())
def test_kill9_mid_step_then_the_next_run_starts_safe_and_passes(
    tmp_path: Path, step: str, procedure: Path
) -> None:
    cell = run_crash_cell(step, tmp_path, procedure)
    assert cell.killed_code == -9
    found = cell.found
    # the bench as the dead station left it: not safe (else the cell proves nothing)
    assert found["supply"]["output"] is True, found["supply"]
    if step not in ("power_identify", "program"):  # program writes with the stream stopped
        assert found["sockets"]["1"]["stream_enabled"] is True
    if step.startswith(CHAMBER_AWAY):  # on its way to the next temperature (or overshoot)
        assert found["chamber"]["setpoint_c"] != pytest.approx(SAFE_TEMP_C)
    if step in TABLE_TURNING:
        assert found["table"]["enabled"] and abs(found["table"]["rate_dps"]) > 1.0
    assert cell.crashed_folder is not None

    _the_next_run_passes(cell, procedure)
    # the bench's own truth when the new run's power_identify began: safe, streams stopped
    at_power = cell.at_power
    assert at_power["safe"]["all"], at_power["safe"]
    assert at_power["table"]["enabled"] is False and abs(at_power["table"]["rate_dps"]) < 1e-6
    assert at_power["supply"]["output"] is False
    assert at_power["chamber"]["setpoint_c"] == pytest.approx(SAFE_TEMP_C)
    assert not any(s["stream_enabled"] for s in at_power["sockets"].values())
    # the crashed run: recovered (ERROR, naming the crash), sealed, no lock left
    crashed = read_record(cell.crashed_folder)
    assert crashed.verdict is Verdict.ERROR
    assert "stopped during the run" in crashed.reason
    assert not (cell.crashed_folder / ".running").exists()
    assert verify_folder(cell.crashed_folder).status is Status.INTACT
    # the new run says what it found and read back before its first step
    assert cell.new_folder is not None
    start = read_record(cell.new_folder).analysis.start_safe_state
    assert start is not None and start.all_safe, start
    assert "STREAM? 0" in start.instruments["streams"].detail
    assert cell.kill_to_safe_station_s is not None and cell.kill_to_safe_wall_s is not None


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
    starts = [e for e in record.events if e.message.startswith(START_SAFE_EVENT)]
    assert len(starts) == 4  # table, streams, supply, chamber: its own pass, once


def _the_next_run_passes(cell: Any, procedure: Path) -> None:
    """The run after the crash ends with its verdict: PASS. Over ramp_short.yaml's 2 C span
    the temperature coefficients are not judged to the product's limits (U (k = 2) of the
    bias's 0.054 deg/s/C against +-0.03): there a FAIL on them alone also counts, the run
    having measured to its end (exit 1, never 2)."""
    if procedure == RAMP_SHORT and cell.code == 1:
        assert cell.new_folder is not None, cell.stdout + cell.stderr
        record = read_record(cell.new_folder)  # the record, not the console's words
        assert record.verdict is Verdict.FAIL and record.failed_measurements, record.reason
        assert all(re.fullmatch(r"\w+_temp_coeff_\w+(@\w+)?", name)
                   for name in record.failed_measurements), record.failed_measurements
        assert record.calibration is not None  # measured to its end, then not programmed
        return
    assert cell.code == 0, cell.stdout + cell.stderr
    assert f"socket 1 {SERIAL}: PASS" in cell.stdout
