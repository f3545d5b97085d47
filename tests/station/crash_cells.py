"""Crash cells: kill -9 of a real `station run` mid-step, then a new `station run` on the same
bench (tests/station/test_start_safe.py and `benchmarks/bench_faults.py --crashes`).

The bench runs as its own process (`station bench --state FILE --lockstep`), so it outlives
the station and its truth can be read; the station runs as a real `station run --sim-bench
FILE` process, watched by tests/station/run_hooked.py: it freezes the run mid-step (in
lockstep the bench's world then stands still exactly there) for the kill, and reads the
bench's truth when `power_identify` begins in the new run.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.sim.control_client import ControlClient
from procedures.runtime.record import read_record

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"
RAMP_SHORT = ROOT / "tests/procedures/data/ramp_short.yaml"  # its safe_temp_c also 25 C
HOOK = Path(__file__).with_name("run_hooked.py")
SERIAL = "SIM-0001"
SAFE_TEMP_C = 25.0  # short.yaml's chamber.safe_temp_c
START_SAFE_EVENT = "safe before the first step"
RAMP_FINISH_S = 420  # wall s for the new run's whole ramp in lockstep

# step[#N: its Nth beginning] -> station s into it when the run is frozen and killed ('' =
# program: after its first calibration write, the step takes no station time)
KILL_POINTS = {
    "power_identify": "1.0",  # supply on, settling
    "thermal#3": "10",  # the chamber on its way from 25 to 35 C, streams on
    "bias": "5",
    "rate_table": "15",  # the table at a plateau
    "stop_method": "6",
    "program": "",
    "verify": "8",  # the table turning again (at -150 deg/s, after the rest window)
}
# the same in ramp_short.yaml's ramp: the chamber heading for the product's maximum, the
# table cycling through the rate set (past skip_s: the record kept for the fit)
RAMP_KILL_POINTS = {"ramp_calibration": "45"}


class CellFailed(RuntimeError):
    """The cell could not be run as planned (the message says where it went wrong)."""


def env(folder: Path) -> dict[str, str]:
    # every station process of a cell shares the machine's lock folder with every other
    # station and bench of the test run (a bench passes over a pty number a station holds)
    del folder
    return dict(os.environ, PYTHONPATH=str(ROOT))


@contextlib.contextmanager
def bench_process(folder: Path) -> Iterator[Path]:
    """`station bench --lockstep` with one good part; yields its state file."""
    folder.mkdir(parents=True, exist_ok=True)
    sim = folder / "sim.yaml"
    sim.write_text(f"parts:\n  - {{socket: 1, serial: {SERIAL}}}\n", encoding="utf-8")
    state = folder / "bench.json"
    log = (folder / "bench.log").open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "station", "bench", "--state", str(state), "--lockstep",
         "--config", str(sim)],
        cwd=ROOT, env=env(folder), stdout=log, stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 60
        while not state.exists():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise CellFailed(f"the bench did not start: {(folder / 'bench.log').read_text()}")
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
    folder: Path, state: Path, out: Path, marks: Path, *hooks: str, procedure: Path = SHORT
) -> subprocess.Popen[str]:
    """`station run --sim-bench STATE` (short.yaml, one part) with run_hooked.py's hooks."""
    return subprocess.Popen(
        [sys.executable, str(HOOK), str(marks), *hooks, "--", "run", "--sim-bench", str(state),
         "--dut", SERIAL, "--procedure", str(procedure), "--out", str(out)],
        cwd=ROOT, env=env(folder), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def read_mark(marks: Path, key: str) -> dict[str, Any] | None:
    if not marks.exists():
        return None
    for line in marks.read_text().splitlines():
        entry = json.loads(line)
        if key in entry:
            return entry
    return None


def wait_mark(
    marks: Path, key: str, proc: subprocess.Popen[str], timeout_s: float = 90
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        entry = read_mark(marks, key)
        if entry is not None:
            return entry
        if proc.poll() is not None:
            out, err = proc.communicate()
            raise CellFailed(
                f"the run ended (exit {proc.returncode}) before {key!r}:\n{out}\n{err}"
            )
        time.sleep(0.02)
    proc.kill()
    raise CellFailed(f"no {key!r} mark within {timeout_s} s")


def finish(proc: subprocess.Popen[str], timeout_s: float = 180) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise CellFailed(f"the run did not end within {timeout_s} s:\n{out}\n{err}") from None
    return proc.returncode, out, err


@dataclass
class CrashCell:
    step: str
    killed_code: int = 0
    found: dict[str, Any] = field(default_factory=dict)  # the bench's truth after the kill
    at_power: dict[str, Any] = field(default_factory=dict)  # truth as power_identify began
    code: int = -1  # the new run's exit code
    stdout: str = ""
    stderr: str = ""
    crashed_folder: Path | None = None
    new_folder: Path | None = None
    # kill -9 -> the new run's safe-state pass read every instrument back safe
    kill_to_safe_station_s: float | None = None  # world time (lockstep: the bench's)
    kill_to_safe_wall_s: float | None = None  # includes starting the new station process
    wall_s: float = 0.0


def run_crash_cell(step: str, folder: Path, procedure: Path | None = None) -> CrashCell:
    """Freeze a run KILL_POINTS[step] (RAMP_KILL_POINTS[step] in the ramp procedure, the
    default for those) into `step`, kill -9 it, read the bench, run `procedure` again."""
    if procedure is None:
        procedure = RAMP_SHORT if step in RAMP_KILL_POINTS else SHORT
    wall0 = time.monotonic()
    cell = CrashCell(step)
    out = folder / "out"
    kill_at = {**KILL_POINTS, **RAMP_KILL_POINTS}[step]
    with bench_process(folder) as state:
        crashed = station_run(folder, state, out, folder / "crashed.jsonl",
                              "--freeze-at", f"{step}:{kill_at}", procedure=procedure)
        frozen = wait_mark(folder / "crashed.jsonl", "frozen", crashed)
        if frozen["frozen"] != step.partition("#")[0]:
            raise CellFailed(f"frozen in {frozen['frozen']}, not {step}")
        crashed.kill()  # SIGKILL: no handler, no safe state, no record written
        killed_utc = dt.datetime.now(dt.UTC)
        crashed.communicate(timeout=10)
        cell.killed_code = crashed.returncode
        cell.found = truth(state)
        folders = list(out.glob(f"*_{SERIAL}"))
        cell.crashed_folder = folders[0] if len(folders) == 1 else None
        marks = folder / "new.jsonl"
        cell.code, cell.stdout, cell.stderr = finish(
            station_run(folder, state, out, marks, "--truth-at", "power_identify",
                        procedure=procedure), RAMP_FINISH_S if procedure == RAMP_SHORT else 180
        )
        cell.at_power = (read_mark(marks, "truth") or {}).get("truth", {})
    cell.new_folder = next((f for f in out.glob(f"*_{SERIAL}") if f != cell.crashed_folder), None)
    if cell.new_folder is not None:
        _times(cell, killed_utc)
    cell.wall_s = time.monotonic() - wall0
    return cell


def _times(cell: CrashCell, killed_utc: dt.datetime) -> None:
    assert cell.new_folder is not None
    record = read_record(cell.new_folder)
    start = record.analysis.start_safe_state
    if start is None or not start.all_safe:
        return
    safe_at = [s.safe_at_station_s for s in start.instruments.values()]
    cell.kill_to_safe_station_s = max(max(safe_at) - float(cell.found["time_s"]), 0.0)
    last = max(
        dt.datetime.fromisoformat(e.time_utc)
        for e in record.events
        if e.message.startswith(START_SAFE_EVENT)
    )
    cell.kill_to_safe_wall_s = (last - killed_utc).total_seconds()
