"""The fault grid: every fault kind injected through the simulated bench's control channel at
every step it applies to (tests/procedures/fault_grid.py), one fresh bench per cell.

Prints one line per cell, then the counts (cells correct, every instrument safe by the bench's
truth, data kept) and the time from the fault to the station's read-back safe state, in
station seconds (median, max; cells where an instrument could not be made safe have no such
time and are counted apart), with the wall seconds from the fault to the run's end.

The bench runs in lockstep, as the tests do: a link's reply timeouts then cost wall seconds
and no station seconds, so the slow-link cells are listed apart. `--speed 200` runs every cell
on a scaled clock instead (the grid before lockstep), where a slow link's wall seconds become
many station seconds.

    python3 benchmarks/bench_faults.py [--quick] [--speed X] [--only FAULT ...] [--steps STEP ...]

`--signals` runs the signal grid instead (tests/station/signal_grid.py): SIGTERM, SIGINT,
SIGHUP, SIGQUIT and a double SIGTERM sent to `station run` and `station ui` in each phase, the
bench its own process; per signal kind the time from the signal to the safe state in station
seconds (the stop request to the last instrument read back safe, from the record) and wall
seconds (the signal to the bench's own truth all safe), and to the process's exit.

    python3 benchmarks/bench_faults.py --signals [--quick] [--commands run ui]
        [--phases PHASE ...] [--kinds SIGTERM ...]

`--crashes` runs the crash cells instead (tests/station/crash_cells.py): a real `station run`
on a bench of its own process, killed with -9 mid-step (each step, or those of --steps), then a
new `station run` on that bench; it prints the time from the kill to the new run's safe state
before its first step (every instrument read back safe): station seconds (the bench in
lockstep stands still between the two runs, so these are the seconds the pass itself takes,
chiefly the table braking) and wall seconds (with the new process's start), median and max.

    python3 benchmarks/bench_faults.py --crashes [--steps STEP ...]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "procedures"))

import fault_grid  # noqa: E402

sys.path.insert(0, str(ROOT / "tests" / "station"))
import signal_grid  # noqa: E402

if TYPE_CHECKING:
    from tests.station.crash_cells import CrashCell


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the representative cells only")
    ap.add_argument("--speed", type=float, default=None,
                    help=f"a scaled clock (e.g. {fault_grid.GRID_SPEED:g}) instead of lockstep")
    ap.add_argument("--only", nargs="*", default=None, help="fault ids to run")
    ap.add_argument("--steps", nargs="*", default=None, help="steps to run")
    ap.add_argument("--signals", action="store_true", help="the signal grid instead")
    ap.add_argument("--commands", nargs="*", default=None, help="with --signals: run, ui")
    ap.add_argument("--phases", nargs="*", default=None, help="with --signals: phases to run")
    ap.add_argument("--kinds", nargs="*", default=None, help="with --signals: signal kinds")
    ap.add_argument("--crashes", action="store_true",
                    help="kill -9 cells: crash mid-step, then the next start's safe state")
    args = ap.parse_args(argv)
    if args.signals:
        return signal_main(args)
    if args.crashes:
        return crash_cells(args.steps)
    cells = list(fault_grid.REPRESENTATIVE) if args.quick else fault_grid.grid_cells()
    if args.only:
        cells = [c for c in cells if c[0] in args.only]
    if args.steps:
        cells = [c for c in cells if c[1] in args.steps]
    results = []
    wall0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        for i, (fault_id, step) in enumerate(cells):
            cell = fault_grid.run_cell(fault_id, step, Path(tmp) / f"c{i}", args.speed)
            results.append(cell)
            t = "-" if cell.fault_to_safe_s is None else f"{cell.fault_to_safe_s:.1f}"
            w = "-" if cell.fault_to_end_wall_s is None else f"{cell.fault_to_end_wall_s:.1f}"
            print(
                f"{fault_id:18s} {step:15s} {cell.verdict:8s} correct={cell.correct!s:5s} "
                f"safe={cell.all_safe!s:5s} kept={cell.data_kept!s:5s} fault->safe {t:>7s} s  "
                f"fault->end {w:>5s} wall s ({cell.wall_s:.0f} wall s)"
                + (f"  PROBLEMS: {'; '.join(cell.problems)}" if cell.problems else ""),
                flush=True,
            )
    n = len(results)
    correct = sum(c.correct for c in results)
    safe = sum(c.all_safe for c in results)
    reported = sum((not c.all_safe) and c.safe_or_reported for c in results)
    kept = sum(c.data_kept for c in results)
    mode = "in lockstep" if args.speed is None else f"at {args.speed:g}x"
    print(f"\nfault grid {mode}: {n} cells ({time.monotonic() - wall0:.0f} s wall)")
    print(f"  correct (ERROR/ABORTED, fault named, safe or reported, data kept): {correct}/{n}")
    print(f"  every instrument safe (bench truth): {safe}/{n}; "
          f"left unsafe but named on the record and certificate: {reported}/{n - safe}")
    print(f"  data kept (record.json, raw.h5, certificate.pdf): {kept}/{n}")
    slow = {"table_link_slow", "chamber_link_slow"}
    for label, group in (
        ("fault -> safe state", [c for c in results if c.fault not in slow]),
        ("fault -> safe state, slow Modbus link", [c for c in results if c.fault in slow]),
    ):
        times = [c.fault_to_safe_s for c in group if c.fault_to_safe_s is not None]
        walls = [c.fault_to_end_wall_s for c in group if c.fault_to_end_wall_s is not None]
        if times:
            med, top = statistics.median(times), max(times)
            print(f"  {label}: median {med:.1f} s, max {top:.1f} s station ({len(times)} "
                  f"cells); fault -> end of run: median {statistics.median(walls):.1f} s, "
                  f"max {max(walls):.1f} s wall")
    return 0 if correct == n else 1


def signal_cells(args: argparse.Namespace) -> list[tuple[str, str, str]]:
    cells = list(signal_grid.REPRESENTATIVE) if args.quick else signal_grid.grid_cells()
    for attr, index in (("commands", 0), ("phases", 1), ("kinds", 2)):
        wanted = getattr(args, attr)
        if wanted:
            cells = [c for c in cells if c[index] in wanted]
    return cells


def signal_main(args: argparse.Namespace) -> int:
    """The signal grid: one line per cell, then the figures per signal kind."""
    results = []
    wall0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        for i, (command, phase, kind) in enumerate(signal_cells(args)):
            try:
                cell = signal_grid.run_cell(command, phase, kind, Path(tmp) / f"s{i}")
            except signal_grid.DiskUnavailable as exc:  # a full-disk cell needs a tmpfs
                print(f"{command:3s} {phase:13s} {kind:15s} NOT RUN: {exc}", flush=True)
                continue
            results.append(cell)
            print(_signal_line(cell), flush=True)
    n = len(results)
    correct = sum(c.correct for c in results)
    print(f"\nsignal grid: {n} cells ({time.monotonic() - wall0:.0f} s wall)")
    print(f"  correct (bench truth safe after exit, record ended and sealed, indexed, no lock, "
          f"exit 2): {correct}/{n}")
    for kind in signal_grid.SIGNALS:
        print(_signal_figures(kind, [c for c in results if c.signal == kind]))
    return 0 if correct == n else 1


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _signal_line(cell: signal_grid.SignalCell) -> str:
    return (
        f"{cell.command:3s} {cell.phase:13s} {cell.signal:15s} {cell.verdict:8s} "
        f"exit={cell.exit_code!s:3s} correct={cell.correct!s:5s} "
        f"signal->safe {_fmt(cell.fault_to_safe_s):>6s} station s "
        f"{_fmt(cell.fault_to_safe_wall_s):>5s} wall s, signal->exit "
        f"{_fmt(cell.fault_to_exit_wall_s):>5s} wall s ({cell.wall_s:.0f} wall s)"
        + (f"  PROBLEMS: {'; '.join(cell.problems)}" if cell.problems else "")
    )


def _signal_figures(kind: str, cells: list[signal_grid.SignalCell]) -> str:
    """Median and max per kind; the certificate cells count for the exit only (the run had
    ended and the bench was safe before the signal)."""
    parts = [f"  {kind}: {len(cells)} cells"]
    running = [c for c in cells if c.phase != "certificate"]
    for label, values in (
        ("signal->safe station s", [c.fault_to_safe_s for c in running]),
        ("signal->safe wall s", [c.fault_to_safe_wall_s for c in running]),
        ("signal->exit wall s", [c.fault_to_exit_wall_s for c in cells]),
    ):
        got = [v for v in values if v is not None]
        if got:
            parts.append(f"{label} median {statistics.median(got):.2f} max {max(got):.2f}")
    return "; ".join(parts)


def crash_cells(steps: list[str] | None) -> int:
    """kill -9 mid-step, then a new run on the same bench: one line per cell, then the time
    from the kill to the new run's read-back safe state (station and wall s, median and max)."""
    from tests.station import crash_cells as cc

    chosen = [s for s in {**cc.KILL_POINTS, **cc.RAMP_KILL_POINTS} if not steps or s in steps]
    results = []
    wall0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        for step in chosen:
            try:
                cell = cc.run_crash_cell(step, Path(tmp) / step)
            except cc.CellFailed as exc:
                print(f"kill -9 in {step:15s} NOT RUN: {str(exc).splitlines()[0]}", flush=True)
                continue
            correct = _crash_correct(cell)  # reads the run folders while they exist
            results.append((cell, correct))
            print(_crash_line(cell) + f" correct={correct}", flush=True)
    ok = [c for c, correct in results if correct]
    print(f"\ncrash cells in lockstep: {len(chosen)} cells ({time.monotonic() - wall0:.0f} s "
          f"wall)")
    print(f"  correct (bench safe when power_identify began, crashed run recovered, new run "
          f"PASS): {len(ok)}/{len(chosen)}")
    station = [c.kill_to_safe_station_s for c in ok if c.kill_to_safe_station_s is not None]
    wall = [c.kill_to_safe_wall_s for c in ok if c.kill_to_safe_wall_s is not None]
    if station and wall:
        print(f"  kill -9 -> safe state at the next start: median {statistics.median(station):.1f}"
              f" s, max {max(station):.1f} s station; median {statistics.median(wall):.1f} s, "
              f"max {max(wall):.1f} s wall ({len(wall)} cells)")
    return 0 if len(ok) == len(chosen) else 1


def _crash_correct(c: CrashCell) -> bool:
    from procedures.runtime.record import Verdict, read_record

    if c.code != 0 or not c.at_power.get("safe", {}).get("all") or c.crashed_folder is None:
        return False
    return read_record(c.crashed_folder).verdict is Verdict.ERROR


def _crash_line(c: CrashCell) -> str:
    found = c.found
    left = (f"left: table {found['table']['rate_dps']:.0f} deg/s "
            f"{'enabled' if found['table']['enabled'] else 'disabled'}, supply "
            f"{'on' if found['supply']['output'] else 'off'}, chamber "
            f"{found['chamber']['setpoint_c']:g} C, stream "
            f"{'on' if found['sockets']['1']['stream_enabled'] else 'off'}")
    t = "-" if c.kill_to_safe_station_s is None else f"{c.kill_to_safe_station_s:.1f}"
    w = "-" if c.kill_to_safe_wall_s is None else f"{c.kill_to_safe_wall_s:.1f}"
    safe = c.at_power.get("safe", {}).get("all")
    return (f"kill -9 in {c.step:15s} {left:70s} next run exit {c.code} safe at power_identify="
            f"{safe!s:5s} kill->safe {t:>5s} s station {w:>5s} s wall ({c.wall_s:.0f} wall s)")


if __name__ == "__main__":
    raise SystemExit(main())
