"""The fault x step grid: one simulated-bench run per cell, a fault injected through the bench's
control channel when the step starts, and the cell judged on what a factory needs.

The bench runs in lockstep: station time is physics time, so every cell measures the same
part the same way up to its fault, and the fault comes at a station time (a clock waiter),
not after a wall timer that machine load stretches. A link's reply timeouts are wall seconds
there, as on a real bench. `speed` runs a cell on a scaled clock instead (bench_faults.py).

A cell is correct when the run ends ERROR or ABORTED with the fault named in its reason, every
instrument is safe by the bench's own truth or the station says which one is not (in the
record and on page one of the certificate, never claiming safe what is not), and the data are
kept (record.json, raw.h5, certificate.pdf). Used by tests/procedures/test_fault_grid.py and
benchmarks/bench_faults.py (no relative imports: the benchmark imports this file directly).
"""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from drivers.sim.launcher import BenchStartError, launch_bench
from procedures.engine.safe_state import SafeStatePolicy
from procedures.runtime.progress import ProgressEvent
from procedures.runtime.record import RAW_DATA_FILE, Verdict, read_record
from station.endpoints import Endpoints
from station.station_file import load_settings
from station.uut import UutRunner
from tests.tools import need

GRID_PROCEDURE = Path(__file__).resolve().parent / "data" / "grid.yaml"
# On a scaled clock (`speed`, the benchmark's option) a wall hiccup of milliseconds is seconds
# of station time on a shared machine, and the stop method's scatter widens (|E_n| beyond 3
# against the table in about 1 run in 6 at 200x under two CPU hogs). A part failing that
# judgement before the faulted step would leave the cell untested, so a scaled run's product
# has that limit opened. In lockstep the shipped product is judged as it is.
OPENED_LIMITS = {"stop_table_consistency": {"low": -100.0, "high": 100.0, "units": "1"}}
SERIAL = "SIM-0901"
GRID_SPEED = 200.0  # the benchmark's scaled clock, when asked for one
# A lost link is retried for 2 station minutes by default, which in lockstep (speed 1) is 2
# wall minutes per cell. The grid gives the pass 10 wall seconds: the least any pass gets
# (SafeStatePolicy.wall_floor_s), and what the grid gave it at 200x before it ran in lockstep.
GRID_SAFE_STATE = SafeStatePolicy(deadline_s=10.0)
STEPS = ("power_identify", "thermal", "bias", "rate_table", "stop_method", "program", "verify")
ALL = STEPS
AT_REST_AND_MOVING = ALL
MOVING = ("rate_table", "stop_method", "verify")
# station seconds into the step at which the fault is injected: while the table turns
INJECT_AFTER_S = {"rate_table": 3.0, "stop_method": 4.0, "verify": 5.0}
# bench truth key -> the station's name for the instrument
TRUTH_KEYS = {
    "table_stopped_and_disabled": "rate_table",
    "supply_off": "supply",
    "chamber_safe": "chamber",
}


@dataclass(frozen=True)
class Fault:
    """A fault kind as injected, the words (any of) its reason must hold, the steps it
    applies to."""

    id: str
    kind: str
    params: dict[str, Any]
    words: tuple[str, ...]
    steps: tuple[str, ...] = ALL


FAULTS = (
    Fault("table_link_lost", "modbus_drop", {"target": "table"}, ("rate table",)),
    Fault("table_link_slow", "modbus_delay", {"target": "table", "delay_s": 1.5}, ("rate table",)),
    Fault(
        "chamber_link_lost",
        "modbus_drop",
        {"target": "chamber"},
        ("chamber",),
        ("power_identify", "thermal", "bias", "rate_table", "verify"),
    ),
    Fault(
        "chamber_link_slow",
        "modbus_delay",
        {"target": "chamber", "delay_s": 1.5},
        ("chamber",),
        ("thermal", "bias", "verify"),
    ),
    Fault("estop", "table_fault", {"code": "estop"}, ("emergency stop",)),
    Fault("interlock", "interlock_open", {}, ("interlock",)),
    Fault(
        "following_error", "table_fault", {"code": "following_error"}, ("following error",), MOVING
    ),
    Fault(
        "chamber_fault",
        "chamber_stuck",
        {"report_fault": True},
        ("chamber reports a fault",),
        ("thermal", "bias", "rate_table"),
    ),
    Fault(
        "supply_short",
        "supply_short",
        {"socket": 1},
        ("current-limiting",),
        ("power_identify", "thermal", "bias", "rate_table", "verify"),
    ),
    # a damaged stream loses enough frames that every analysis window sees it: a window holds
    # ~150 frames and tolerates 2 lost, which at a 2 % drop rate still happens 4 times in 10
    # (the cell was a coin flip); at 10 % (drop) or 0.5 % of bytes (~12 % of frames) a clean
    # window after the fault has odds below 1e-4
    Fault(
        "stream_drop",
        "stream_drop",
        {"socket": 1, "frame_drop_rate": 0.10},
        ("frames lost",),
        ("bias", "rate_table", "stop_method", "verify"),
    ),
    Fault(
        "stream_corrupt",
        "stream_corrupt",
        {"socket": 1, "byte_error_rate": 0.005},
        ("frames lost", "stream corrupted"),
        ("bias", "rate_table", "verify"),
    ),
    Fault(
        "part_silent",
        "part_silent",
        {"socket": 1},
        ("stopped streaming", "stopped sending", "no samples", "not responding"),
        ("power_identify", "thermal", "rate_table", "verify"),
    ),
)
FAULTS_BY_ID = {f.id: f for f in FAULTS}

# the default test run: one cell per mechanism (retried safe state through a slow link, a
# safe-state failure on the certificate, the watchdog at rest, a chamber FAULT, a damaged
# window, a part fault)
REPRESENTATIVE = (
    ("table_link_slow", "rate_table"),
    ("table_link_lost", "verify"),
    ("estop", "thermal"),
    ("chamber_fault", "thermal"),
    ("stream_drop", "verify"),
)


def grid_procedure(folder: Path) -> Path:
    """The grid's procedure with a product whose OPENED_LIMITS are opened, written in
    `folder` (the shipped files stay as they are)."""
    data = yaml.safe_load(GRID_PROCEDURE.read_text())
    product_path = (GRID_PROCEDURE.parent / data["product"]).resolve()
    product = yaml.safe_load(product_path.read_text())
    product["limits"].update(OPENED_LIMITS)
    product.pop("consistency", None)  # the opened limit replaces the product's derived one
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "grid-product.yaml").write_text(yaml.safe_dump(product, sort_keys=False))
    data["product"] = "grid-product.yaml"
    copy = folder / GRID_PROCEDURE.name
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    return copy


def grid_cells() -> list[tuple[str, str]]:
    return [(f.id, step) for f in FAULTS for step in f.steps]


@dataclass
class CellResult:
    fault: str
    step: str
    verdict: str = ""
    reason: str = ""
    injected: bool = False
    fault_named: bool = False
    truth_safe: dict[str, bool] = field(default_factory=dict)
    station_safe: dict[str, bool] = field(default_factory=dict)
    certificate_text: str = ""
    data_kept: bool = False
    fault_to_safe_s: float | None = None
    # wall seconds from the fault to the run's end (in lockstep a link's reply timeouts cost
    # wall time, not station time)
    fault_to_end_wall_s: float | None = None
    wall_s: float = 0.0
    problems: list[str] = field(default_factory=list)

    @property
    def all_safe(self) -> bool:
        return bool(self.truth_safe) and all(self.truth_safe.values())

    @property
    def safe_or_reported(self) -> bool:
        """Every instrument safe by the bench's truth, or named unsafe by the station (in the
        record and on the certificate's first page)."""
        for name, safe in self.truth_safe.items():
            if safe:
                continue
            if self.station_safe.get(name, True):
                return False
            if "SAFE STATE FAILED" not in self.certificate_text:
                return False
        return bool(self.truth_safe)

    @property
    def correct(self) -> bool:
        return (
            self.injected
            and self.verdict in (str(Verdict.ERROR), str(Verdict.ABORTED))
            and self.fault_named
            and self.safe_or_reported
            and self.data_kept
        )


def first_page_text(pdf: Path) -> str:
    """Page one of a PDF as text ('' when there is no PDF)."""
    need("pdftotext")
    if not pdf.exists():
        return ""
    done = subprocess.run(
        ["pdftotext", "-f", "1", "-l", "1", "-layout", str(pdf), "-"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    return done.stdout


def run_cell(fault_id: str, step: str, out: Path, speed: float | None = None) -> CellResult:
    """Run one cell on a fresh bench (in lockstep, or at `speed`) and judge it (a bench that
    fails to start on a loaded machine is started again: that is the test rig, not the
    cell)."""
    for attempt in range(3):
        try:
            return _run_cell(fault_id, step, out / f"try{attempt}", speed)
        except BenchStartError:
            if attempt == 2:
                raise
    raise AssertionError("unreachable")


def _run_cell(fault_id: str, step: str, out: Path, speed: float | None) -> CellResult:
    fault = FAULTS_BY_ID[fault_id]
    cell = CellResult(fault_id, step)
    wall0 = time.monotonic()
    part = {"socket": 1, "serial": SERIAL}
    with launch_bench(
        config={"parts": [part]},
        speed=speed,
        sockets=1,
        start_timeout_s=60.0,
        lockstep=speed is None,
    ) as bench:
        procedure = GRID_PROCEDURE
        if speed is not None:
            procedure = grid_procedure(out.with_name(out.name + "-procedure"))
        runner = UutRunner(
            load_settings(),
            procedure_path=procedure,
            out=out,
            endpoints=Endpoints.of_bench(bench.endpoints),
            certificate=True,
            operator="fault-grid",
            safe_state_policy=GRID_SAFE_STATE,
        )
        injector = _Injector(runner, step, lambda: bench.control.fault(fault.kind, **fault.params))
        runner.progress.subscribe(injector.on_event)
        result = runner.run({1: SERIAL})
        ended_wall = time.monotonic()
        truth = bench.control.truth()
    injected_at = injector.at_station_s
    if injector.at_wall_s is not None:
        cell.fault_to_end_wall_s = ended_wall - injector.at_wall_s
    cell.wall_s = time.monotonic() - wall0
    cell.injected = injected_at is not None
    folder = result.folders[1]
    rec = read_record(folder)
    cell.verdict, cell.reason = str(rec.verdict), rec.reason
    cell.fault_named = any(w.lower() in rec.reason.lower() for w in fault.words)
    cell.truth_safe = {TRUTH_KEYS[k]: bool(v) for k, v in truth["safe"].items() if k in TRUTH_KEYS}
    report = rec.analysis.safe_state_report
    instruments = report.instruments if report is not None else {}
    cell.station_safe = {name: s.safe for name, s in instruments.items()}
    pdf = folder / "certificate.pdf"
    cell.certificate_text = first_page_text(pdf)
    cell.data_kept = all((folder / f).exists() for f in ("record.json", RAW_DATA_FILE)) and (
        pdf.exists()
    )
    times = [s.safe_at_station_s for s in instruments.values() if s.safe]
    if injected_at is not None and times and len(times) == len(instruments):
        # safe_at_station_s is rounded to 1 ms: an instrument already safe reads -0.0
        cell.fault_to_safe_s = max(max(float(t) for t in times) - injected_at, 0.0)
    if not cell.correct:
        cell.problems = _problems(cell)
    return cell


class _Injector:
    """Injects the fault `INJECT_AFTER_S` station seconds into `step`: from a clock waiter in
    lockstep (at a station time, whatever the machine's load), after a wall timer on a scaled
    clock."""

    def __init__(self, runner: UutRunner, step: str, fault: Callable[[], object]) -> None:
        self.runner, self.step, self.fault = runner, step, fault
        self.at_station_s: float | None = None  # when the fault went in (None: never)
        self.at_wall_s: float | None = None
        self._fired = threading.Event()

    def on_event(self, ev: ProgressEvent) -> None:
        if ev.kind != "step" or ev.step != self.step or self._fired.is_set():
            return
        self._fired.set()
        ctx = self.runner.context
        if ctx is None:
            return
        after_s = INJECT_AFTER_S.get(self.step, 0.0)
        clock = ctx.clock
        if after_s <= 0:
            self._inject()
        elif hasattr(clock, "add_waiter"):
            due_s = clock.now_s() + after_s

            def waiter(t_s: float, reply: object) -> None:
                if t_s >= due_s and self.at_station_s is None:
                    clock.remove_waiter(waiter)
                    self._inject()

            clock.add_waiter(waiter)
        else:
            timer = threading.Timer(clock.wall_timeout_s(after_s), self._inject)
            timer.daemon = True
            timer.start()

    def _inject(self) -> None:
        ctx = self.runner.context
        if ctx is None:  # the run ended before the fault was due
            return
        self.at_station_s, self.at_wall_s = ctx.clock.now_s(), time.monotonic()
        self.fault()


def _problems(cell: CellResult) -> list[str]:
    out = []
    if not cell.injected:
        out.append(f"the fault was never injected (step {cell.step} not reached)")
    if cell.verdict not in (str(Verdict.ERROR), str(Verdict.ABORTED)):
        out.append(f"verdict {cell.verdict}")
    if not cell.fault_named:
        out.append(f"fault not named in the reason: {cell.reason!r}")
    if not cell.safe_or_reported:
        out.append(f"unsafe and not reported: truth {cell.truth_safe}, station {cell.station_safe}")
    if not cell.data_kept:
        out.append("record, raw data or certificate missing")
    return out
