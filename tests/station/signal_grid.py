"""The signal grid: SIGTERM, SIGINT, SIGHUP, SIGQUIT and a double SIGTERM (0.2 s apart) sent
to a real `station run --sim` and a real `station ui --sim` process while the run is in a
thermal ramp, a rate plateau, a stop-method move, programming, or its certificate rendering;
and, in the ramp calibration (tests/procedures/data/ramp_short.yaml), while the chamber ramps
and the table turns through the rate set (the ramp record), in the static dwell, and in a
stop-method move at a ramp end. A full disk (the runs folder on a small tmpfs, filled by the
test) during the ramp record is a cell of the same grid: its "signal" is the disk refusing.

The bench is its own process (`station bench`), started here; the station attaches to it
(tests/station/attached_station.py), so its truth is read after the station has exited. A
cell waits for its phase by the bench's truth or the run's record (never a fixed sleep), then
signals, and is judged on:

* the bench's truth after the station exited: the table at rest and disabled, the supply
  off, the chamber at its safe temperature;
* the record: ABORTED (or ERROR) with the signal named - or, for a signal during the
  certificate rendering, the verdict the run had already reached - sealed (`station verify`
  says intact), indexed in the results database, no `.running` lock left;
* the exit code: 2 for a run the signal ended;
* a full disk: the record ERROR naming raw.h5 and the full disk, and raw.h5 readable with
  the samples measured before the disk filled.

Used by tests/station/test_signal_grid.py and benchmarks/bench_faults.py (`--signals`); no
relative imports (the benchmark imports this file directly).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import yaml

import procedures.runtime.rawdata as rawdata
from drivers.sim.launcher import BenchHandle, launch_bench
from procedures.runtime.rawdata import RawDataError, read_raw
from procedures.runtime.record import RunRecord, Verdict, read_record
from station.ui.server import free_port

ROOT = Path(__file__).resolve().parents[2]
ATTACHED = Path(__file__).resolve().parent / "attached_station.py"
PROCEDURE = ROOT / "tests/procedures/data/signal_grid.yaml"
RAMP_PROCEDURE = ROOT / "tests/procedures/data/ramp_short.yaml"
SERIAL = "SIM-0951"
SIGNALS: dict[str, tuple[signal.Signals, ...]] = {
    "SIGTERM": (signal.SIGTERM,),
    "SIGINT": (signal.SIGINT,),
    "SIGHUP": (signal.SIGHUP,),
    "SIGQUIT": (signal.SIGQUIT,),
    "double_SIGTERM": (signal.SIGTERM, signal.SIGTERM),
}
DOUBLE_GAP_S = 0.2  # finding 6 of issue 25: two SIGTERMs 0.2 s apart
RAMP_PHASES = ("ramp_record", "ramp_static", "ramp_stop")
PHASES = ("thermal_ramp", "rate_plateau", "stop_move", "programming", "certificate",
          *RAMP_PHASES)
DISK_FULL = "disk_full"  # not a signal: the runs folder's disk fills (ramp_record only)
COMMANDS = ("run", "ui")
# the bench's speed per phase: the early phases are lengthened (below) and seen at 20x; the
# late ones run the whole short procedure first
SPEED = {"thermal_ramp": 20.0, "rate_plateau": 20.0, "stop_move": 20.0,
         "programming": 40.0, "certificate": 40.0,
         "ramp_record": 20.0, "ramp_static": 40.0, "ramp_stop": 40.0}
# what each early phase's procedure lengthens, so that it lasts wall seconds at its speed
PHASE_EDITS: dict[str, Callable[[dict[str, Any]], None]] = {
    "thermal_ramp": lambda p: p["conditions"].update(temperatures_c=[30.0, 31.0]),
    "rate_plateau": lambda p: _step(p, "rate_table").update(plateau_dwell_s=60.0),
    "stop_move": lambda p: _step(p, "stop_method").update(move_time_s=40.0),
    "ramp_static": lambda p: _step(p, "ramp_calibration").update(static_s=600.0),
    "ramp_stop": lambda p: _step(p, "ramp_calibration")["stop_method"].update(move_time_s=40.0),
}
RAMP_HEATED_C = 40.0  # a setpoint above: the ramp heading for its overshoot (the product's max)
# the ramp record is hit this long (the bench's s) into the ramp (2.25 wall s at 20x): past
# ramp_short.yaml's skip_s (plateaus kept for the fit) and raw.h5's first batch of rows
RAMP_RECORD_S = 45.0
# a full disk comes later: past the first batch of samples in raw.h5 (streams.py: every 5
# wall s, 100 bench s at 20x), so that the cell shows what was written is kept
DISK_FULL_RECORD_S = 130.0
RAMP_END_C = 25.0  # ramp_short.yaml's end setpoint (its chamber.safe_temp_c)
RAW_FLUSH_WALL_S = 6.0  # samples reach raw.h5 in batches every 5 wall s (streams.py) + slack
DISK_FULL_MB = 64  # the tmpfs under the runs folder of a full-disk cell
PROGRAM_HOLD_DELAY_S = 0.3  # Modbus replies slowed while the program step starts (wall s)
TRUTH_KEYS = {
    "table_stopped_and_disabled": "rate_table",
    "supply_off": "supply",
    "chamber_safe": "chamber",
}
# one cell per command in the default test run; the rest is the station_grid
REPRESENTATIVE = (("run", "rate_plateau", "double_SIGTERM"), ("ui", "stop_move", "SIGTERM"))
# the ramp's phases: a run through the station's own signal handling, the signals that end a
# run differently (SIGHUP: the terminal gone; two SIGTERMs: the second while the first's safe
# state runs); through the operator screen once; the full disk during the ramp record
RAMP_SIGNALS = ("SIGTERM", "SIGHUP", "double_SIGTERM")
RAMP_CELLS = (*[("run", p, s) for p in RAMP_PHASES for s in RAMP_SIGNALS],
              ("ui", "ramp_record", "SIGTERM"), ("run", "ramp_record", DISK_FULL))


def _step(procedure: dict[str, Any], name: str) -> dict[str, Any]:
    for item in procedure["steps"]:
        for step in item.get("steps", [item]):
            if step.get("step") == name:
                return step
    raise KeyError(name)


def grid_cells() -> list[tuple[str, str, str]]:
    return [(c, p, s) for c in COMMANDS for p in PHASES if p not in RAMP_PHASES
            for s in SIGNALS] + list(RAMP_CELLS)


@dataclass
class SignalCell:
    command: str
    phase: str
    signal: str
    exit_code: int | None = None
    verdict: str = ""
    reason: str = ""
    hit_step: str = ""  # the step the signal landed in, as the record names it
    truth_safe: dict[str, bool] = field(default_factory=dict)
    sealed: bool = False
    indexed: bool = False
    lock_left: bool = True
    fault_to_safe_s: float | None = None  # station s: stop requested -> last instrument safe
    fault_to_safe_wall_s: float | None = None  # wall s: signal -> the bench's truth all safe
    fault_to_exit_wall_s: float | None = None  # wall s: signal -> the station process gone
    wall_s: float = 0.0
    kept_until_s: float | None = None  # raw.h5's last sample (station s) after a full disk
    output: str = ""
    problems: list[str] = field(default_factory=list)

    @property
    def correct(self) -> bool:
        return not self.problems


def make_station(folder: Path, phase: str, small_disk: bool = False) -> Path:
    """A config folder: station.yaml as shipped (its runs and database in `folder`) with the
    grid's procedure (the ramp's for a ramp phase), lengthened for `phase`, as the default
    procedure. On a small disk the free space a run needs at its start is what that disk
    has (the disk fills during the run)."""
    (folder / "procedures").mkdir(parents=True, exist_ok=True)
    source = RAMP_PROCEDURE if phase in RAMP_PHASES else PROCEDURE
    procedure = yaml.safe_load(source.read_text(encoding="utf-8"))
    procedure["product"] = str((source.parent / procedure["product"]).resolve())
    if phase in PHASE_EDITS:
        PHASE_EDITS[phase](procedure)
    (folder / "procedures" / "signal-grid.yaml").write_text(yaml.safe_dump(procedure))
    station = yaml.safe_load((ROOT / "config/station.yaml").read_text(encoding="utf-8"))
    station.update(output_folder="runs", results_db="runs/results.sqlite",
                   procedure="procedures/signal-grid.yaml")
    station["instruments"]["fixture"]["sockets"] = 1
    if small_disk:
        station["min_free_space_mb"] = DISK_FULL_MB // 2
    (folder / "station.yaml").write_text(yaml.safe_dump(station), encoding="utf-8")
    if _SIGNING:  # the first cell's station key and certificate: making one costs seconds
        shutil.copytree(_SIGNING[0], folder / "signing")
    return folder / "station.yaml"


_SIGNING: list[Path] = []


def _keep_signing(config: Path) -> None:
    if not _SIGNING and (config / "signing" / "station-key.pem").is_file():
        _SIGNING.append(config / "signing")


class _Lines:
    """The station's output, read on a thread (a full pipe must never stall the station)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.text = io.StringIO()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with self._lock:
                self.text.write(line)

    def value(self) -> str:
        with self._lock:
            return self.text.getvalue()

    def join(self) -> None:
        self._thread.join(10)


def _start(command: str, state: Path, station_yaml: Path, log_env: dict[str, str],
           port: int) -> subprocess.Popen[str]:
    args = [sys.executable, str(ATTACHED), str(state)]
    if command == "run":
        args += ["run", "--sim", "--dut", SERIAL, "--station", str(station_yaml)]
    else:
        args += ["ui", "--sim", "--port", str(port), "--station", str(station_yaml)]
    return subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
        text=True, cwd=ROOT, env=log_env, preexec_fn=_hangups_not_ignored,
    )


def _hangups_not_ignored() -> None:
    """A cell's station starts as from a terminal, whatever started the tests: under nohup
    it would inherit SIGHUP ignored, and the station keeps an inherited ignore of SIGHUP."""
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def _start_ui_run(url: str, proc: subprocess.Popen[str], lines: _Lines) -> None:
    """Sign in and START the scanned part through the operator screen's API."""
    deadline = time.monotonic() + 90
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"station ui exited: {lines.value()[-2000:]}")
        try:
            httpx.get(url + "/api/state", timeout=2).raise_for_status()
            break
        except httpx.HTTPError:
            if time.monotonic() > deadline:
                raise RuntimeError(f"station ui did not answer: {lines.value()[-2000:]}") from None
            time.sleep(0.1)
    with httpx.Client(base_url=url, timeout=30) as client:
        csrf = client.get("/api/session").json()["csrf"]
        r = client.post("/api/signin", json={"name": "grid"}, headers={"X-CSRF-Token": csrf})
        r.raise_for_status()
        csrf = r.json().get("csrf", csrf)
        r = client.post("/api/start", json={"serials": {"1": SERIAL}},
                        headers={"X-CSRF-Token": csrf})
        if r.status_code != 200:
            raise RuntimeError(f"START refused: {r.status_code} {r.text}")


def _record(runs: Path) -> dict[str, Any] | None:
    for path in runs.glob(f"*_{SERIAL}/record.json"):
        with contextlib.suppress(OSError, ValueError):
            return dict(json.loads(path.read_text(encoding="utf-8")))
    return None


def _in_phase(phase: str, bench: BenchHandle, runs: Path, state: dict[str, Any]) -> bool:
    """True once the run is in `phase` (the programming phase first slows the bench's Modbus
    replies as the fit starts, so that the program step's first instrument check lasts)."""
    if phase in RAMP_PHASES:
        return _in_ramp_phase(phase, bench.control.truth(), state)
    if phase in ("thermal_ramp", "rate_plateau", "stop_move"):
        truth = bench.control.truth()
        ch, table = truth["chamber"], truth["table"]
        if phase == "thermal_ramp":
            return bool(ch["running"]) and ch["setpoint_c"] >= 29.5 and (
                ch["ramped_setpoint_c"] < ch["setpoint_c"] - 1.0)
        if phase == "rate_plateau":
            return table["mode"] == "rate" and abs(abs(table["rate_dps"]) - 100.0) < 0.5
        return table["mode"] == "position" and abs(table["rate_dps"]) > 0.5
    record = _record(runs)
    if record is None:
        return False
    if phase == "certificate":
        return record.get("verdict") not in (None, "RUNNING")
    timings = record.get("timings") or {}
    if not state.get("held") and sum(k.startswith("stop_method") for k in timings) >= 4:
        bench.control.fault("modbus_delay", target="all", delay_s=PROGRAM_HOLD_DELAY_S)
        state["held"] = True
    return bool(state.get("held")) and "fit" in timings


def _in_ramp_phase(phase: str, truth: dict[str, Any], state: dict[str, Any]) -> bool:
    """The ramp's phases by the bench's truth: the chamber ramping (its ramped setpoint on
    its way) with the table at a plateau of the rate set; the table enabled at rest in rate
    mode, the chamber sent to its end setpoint, after the ramp headed for its overshoot (the
    static dwell; the stop after the ramp comes later); the table moving in position mode (a
    stop-method move, at the top first)."""
    ch, table = truth["chamber"], truth["table"]
    state["heated"] = state.get("heated") or ch["setpoint_c"] > RAMP_HEATED_C
    if phase == "ramp_record":
        ramping = bool(ch["running"]) and abs(ch["ramped_setpoint_c"] - ch["setpoint_c"]) > 1.0
        if ramping and state["heated"]:
            state.setdefault("ramp_from_s", float(truth["time_s"]))
        into_s = float(truth["time_s"]) - state.get("ramp_from_s", np.inf)
        long_enough = into_s >= state.get("ramp_record_s", RAMP_RECORD_S)
        at_plateau = table["mode"] == "rate" and abs(abs(table["rate_dps"]) - 100.0) < 0.5
        return ramping and long_enough and at_plateau
    if phase == "ramp_static":
        at_rest = table["enabled"] and table["mode"] == "rate" and abs(table["rate_dps"]) < 1e-6
        return bool(state["heated"] and at_rest) and abs(ch["setpoint_c"] - RAMP_END_C) < 0.01
    return table["mode"] == "position" and abs(table["rate_dps"]) > 0.5


def run_cell(command: str, phase: str, sig: str, tmp: Path, timeout_s: float = 240.0) -> SignalCell:
    """One cell on a fresh bench; see the module docstring."""
    cell = SignalCell(command, phase, sig)
    wall0 = time.monotonic()
    runs = tmp / "config" / "runs"
    env = dict(os.environ, PYTHONPATH=str(ROOT), TMPDIR=str(tmp))
    with contextlib.ExitStack() as stack:
        if sig == DISK_FULL:
            stack.enter_context(small_disk(runs))
        station_yaml = make_station(tmp / "config", phase, small_disk=sig == DISK_FULL)
        _run_station(cell, station_yaml, runs, env, timeout_s)
    cell.wall_s = time.monotonic() - wall0
    return cell


def _run_station(cell: SignalCell, station_yaml: Path, runs: Path, env: dict[str, str],
                 timeout_s: float) -> None:
    command, phase, sig = cell.command, cell.phase, cell.signal
    with launch_bench(config={"parts": [{"socket": 1, "serial": SERIAL}]},
                      speed=SPEED[phase], sockets=1) as bench:
        port = free_port()
        proc = _start(command, bench.state_path, station_yaml, env, port)
        lines = _Lines(proc)
        try:
            if command == "ui":
                _start_ui_run(f"http://127.0.0.1:{port}", proc, lines)
            state: dict[str, Any] = {}
            if sig == DISK_FULL:
                state["ramp_record_s"] = DISK_FULL_RECORD_S
            deadline = time.monotonic() + timeout_s
            while not _in_phase(phase, bench, runs, state):
                if proc.poll() is not None or time.monotonic() > deadline:
                    cell.problems.append(f"phase {phase} never seen")
                    break
                time.sleep(0.01)
            if not cell.problems and sig == DISK_FULL:
                fill_disk(runs)
            elif not cell.problems:
                _signal_and_watch(cell, proc, bench, SIGNALS[sig])
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            cell.problems.append(f"the station did not exit within {timeout_s:g} s")
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
            lines.join()
        cell.exit_code = proc.returncode
        cell.output = lines.value()
        truth = bench.control.truth()
    cell.truth_safe = {TRUTH_KEYS[k]: bool(v) for k, v in truth["safe"].items() if k in TRUTH_KEYS}
    _judge(cell, runs, station_yaml)
    _keep_signing(station_yaml.parent)


@contextlib.contextmanager
def small_disk(runs: Path) -> Iterator[None]:
    """`runs` on a tmpfs of its own (root only: else the cell is skipped, as
    tests/procedures/test_storage_faults.py's small disk is)."""
    runs.mkdir(parents=True)
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_FULL_MB}m", "tmpfs",
                              str(runs)], capture_output=True, text=True, check=False)
    if mounted.returncode != 0:
        raise DiskUnavailable(f"cannot mount a tmpfs: {mounted.stderr.strip()}")
    try:
        yield
    finally:
        subprocess.run(["umount", "-l", str(runs)], check=False)


class DiskUnavailable(RuntimeError):
    """A full-disk cell cannot have a small disk of its own here."""


def fill_disk(runs: Path) -> None:
    """Fill the runs folder's disk to just under the raw data's reserve: raw.h5's next write
    is refused (the room kept for record.json, the certificate and the index)."""
    st = os.statvfs(runs)
    left = rawdata.RESERVE_BYTES - (64 << 10)
    fd = os.open(runs / "filler", os.O_CREAT | os.O_WRONLY)
    try:
        os.posix_fallocate(fd, 0, st.f_bavail * st.f_frsize - left)
    finally:
        os.close(fd)


def _signal_and_watch(cell: SignalCell, proc: subprocess.Popen[str], bench: BenchHandle,
                      signals: tuple[signal.Signals, ...]) -> None:
    """Send the signals; time the bench's truth to all safe and the process to its exit."""
    t0 = time.monotonic()
    for i, sig in enumerate(signals):
        if i:
            time.sleep(DOUBLE_GAP_S)
        proc.send_signal(sig)
    if cell.phase == "programming":  # the hold has done its work: a normal bench again
        bench.control.clear_faults()
    while proc.poll() is None and time.monotonic() - t0 < 240:
        if cell.fault_to_safe_wall_s is None and bench.control.truth()["safe"]["all"]:
            cell.fault_to_safe_wall_s = time.monotonic() - t0
        time.sleep(0.02)
    cell.fault_to_exit_wall_s = time.monotonic() - t0
    if cell.fault_to_safe_wall_s is None and bench.control.truth()["safe"]["all"]:
        cell.fault_to_safe_wall_s = cell.fault_to_exit_wall_s


def _judge(cell: SignalCell, runs: Path, station_yaml: Path) -> None:
    p = cell.problems
    unsafe = [name for name, ok in cell.truth_safe.items() if not ok]
    if unsafe or not cell.truth_safe:
        p.append(f"bench truth not safe after exit: {unsafe or 'no truth'}")
    folders = sorted(runs.glob(f"*_{SERIAL}"))
    if len(folders) != 1:
        p.append(f"{len(folders)} run folders")
        return
    folder = folders[0]
    rec = read_record(folder)
    cell.verdict, cell.reason = str(rec.verdict), rec.reason
    if "in step " in rec.reason:  # ", in step X" (a signal) or "(in step X)" (an error)
        cell.hit_step = rec.reason.rpartition("in step ")[2].strip(") ")
    cell.lock_left = (folder / ".running").exists()
    cell.sealed = _verify(folder, station_yaml)
    cell.indexed = _indexed(runs / "results.sqlite", folder.name, str(rec.verdict))
    requested = rec.analysis.stop_requested_station_s
    report = rec.analysis.safe_state_report
    instruments = report.instruments if report is not None else {}
    times = [s.safe_at_station_s for s in instruments.values() if s.safe]
    if requested is not None and times and len(times) == len(instruments):
        cell.fault_to_safe_s = max(max(float(t) for t in times) - float(requested), 0.0)
    if cell.phase == "certificate":
        # the run had ended (and the bench was safe) before the signal: its verdict stands
        if rec.verdict is Verdict.RUNNING:
            p.append("record left RUNNING")
    else:
        if cell.signal == DISK_FULL:
            _judge_disk_full(cell, rec, folder)
        elif rec.verdict not in (Verdict.ABORTED, Verdict.ERROR):
            p.append(f"verdict {rec.verdict}, not ABORTED/ERROR")
        elif cell.signal.replace("double_", "") not in rec.reason and "Ctrl-C" not in rec.reason:
            p.append(f"the signal is not named in the reason: {rec.reason!r}")
        step = {"thermal_ramp": "thermal", "rate_plateau": "rate_table",
                "stop_move": "stop_method", "programming": "program",
                **dict.fromkeys(RAMP_PHASES, "ramp_calibration")}[cell.phase]
        if not cell.hit_step.startswith(step):
            p.append(f"the signal landed in step {cell.hit_step!r}, not {step}")
    ended_run = rec.verdict in (Verdict.ABORTED, Verdict.ERROR)
    if ended_run and cell.exit_code != 2:
        p.append(f"exit code {cell.exit_code}, not 2")
    if cell.exit_code not in (0, 1, 2):
        p.append(f"exit code {cell.exit_code}")
    if not cell.sealed:
        p.append("station verify does not call the folder intact")
    if not cell.indexed:
        p.append("not in the results database with its verdict")
    if cell.lock_left:
        p.append(".running lock left")
    if "Traceback" in cell.output:
        p.append("a traceback in the station's output")


def _judge_disk_full(cell: SignalCell, rec: RunRecord, folder: Path) -> None:
    """ERROR naming raw.h5 and the full disk; raw.h5 readable, holding the samples up to
    the batch the disk refused (at most RAW_FLUSH_WALL_S at the cell's speed before the run
    stopped: measured as the disk filled, they had no room)."""
    raw, verdict, reason = folder / "raw.h5", rec.verdict, rec.reason
    if verdict is not Verdict.ERROR:
        cell.problems.append(f"verdict {verdict}, not ERROR")
    if f"cannot write {raw}: No space left on device" not in reason:
        cell.problems.append(f"the full disk is not named in the reason: {reason!r}")
    try:
        times = read_raw(raw)["samples"]["station_time_s"]
    except (RawDataError, KeyError) as exc:
        cell.problems.append(f"raw.h5 not readable after the full disk: {exc}")
        return
    cell.kept_until_s = float(times.max()) if len(times) else None
    stopped_s = min((e.station_time_s for e in rec.events if e.step == "cleanup"), default=0.0)
    lag_s = RAW_FLUSH_WALL_S * SPEED[cell.phase]
    if cell.kept_until_s is None or cell.kept_until_s < stopped_s - lag_s:
        cell.problems.append(f"raw.h5 keeps samples until {cell.kept_until_s} s only, the "
                             f"run stopped at {stopped_s:.1f} s")


def _verify(folder: Path, station_yaml: Path) -> bool:
    """`station verify FOLDER` says intact (run here: the command, without a process start)."""
    from station.cli.main import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        return main(["verify", str(folder), "--station", str(station_yaml)]) == 0


def _indexed(db: Path, run_id: str, verdict: str) -> bool:
    if not db.is_file():
        return False
    with contextlib.closing(sqlite3.connect(db)) as con:
        row = con.execute("select verdict from runs where run_id = ?", (run_id,)).fetchone()
    return row is not None and row[0] == verdict
