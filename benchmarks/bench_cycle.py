"""Cycle time: station time per part for the full procedure with 1, 4 and 8 sockets.

Compared with a lower bound per part: (thermal settling of the part + the measurement time
the target accuracy needs) / sockets, where
  settling    = the time the die itself needed to meet the stability criterion, summed over
                the conditions (from the run's own stability records),
  measurement = per condition, the bias averaging time for the procedure's target accuracy
                (from the part's measured angle random walk) + the plateau and stop-method
                dwells, + the verification dwells.
Also prints the wall time of each simulated cycle. The bench runs in lockstep (station time is
physics time, the wall time is the compute time) unless --speed asks for a scaled clock.

    python3 benchmarks/bench_cycle.py [--sockets 1 4 8] [--speed 100]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.analysis.allan import NoiseModel  # noqa: E402
from procedures.analysis.bias import required_averaging_time_s  # noqa: E402
from procedures.config import load_procedure  # noqa: E402
from procedures.record import read_record  # noqa: E402
from station.uut import run_simulated  # noqa: E402


def cpu_s() -> float:
    """CPU seconds of this process (the station) and its waited children (the bench)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def measurement_floor_s(proc_path: Path, arw_deg_per_sqrt_h: float) -> float:
    """Station seconds spent measuring (bias, plateaus, stop moves, verification) per run."""
    proc, _ = load_procedure(proc_path)
    n_cond = len(proc.conditions.temperatures_c) * len(proc.conditions.supplies_v)
    noise = NoiseModel.from_datasheet(arw_deg_per_sqrt_h=arw_deg_per_sqrt_h)
    bias = proc.settings_of("bias")
    per_cond = required_averaging_time_s(noise, bias.target_accuracy_dps) if bias else 0.0
    table = proc.settings_of("rate_table")
    if table is not None:
        per_cond += len(table.rates_dps) * table.repeats * table.plateau_dwell_s
    sm = proc.settings_of("stop_method")
    if sm is not None:
        per_cond += sm.static_s + sm.repeats * 2 * (sm.move_time_s + sm.static_s)
    verify = 0.0
    check = proc.settings_of("verify")
    if check is not None:
        verify = (len(check.rates_dps) + 1) * check.dwell_s
    return n_cond * per_cond + verify


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sockets", type=int, nargs="+", default=[1, 4, 8])
    ap.add_argument("--speed", type=float, default=None, help="scaled clock (default: lockstep)")
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-rate-table.yaml"))
    args = ap.parse_args()
    proc_path = Path(args.procedure)
    out = Path(tempfile.mkdtemp(prefix="bench-cycle-"))
    rows = []
    for n in args.sockets:
        parts = [{"socket": s, "serial": f"SIM-{7000 + 10 * n + s:04d}"} for s in range(1, n + 1)]
        w0, c0 = time.monotonic(), cpu_s()
        result, _ = run_simulated(parts, procedure_path=proc_path, out=out, speed=args.speed)
        wall, cpu = time.monotonic() - w0, cpu_s() - c0
        recs = [read_record(result.folders[s]) for s in sorted(result.folders)]
        total = max(r.timings.get("total", 0.0) for r in recs)
        settle = min(
            sum(v.get("time_to_stability_s", 0.0) for v in r.analysis.get("stability", {}).values())
            for r in recs
        )
        arws = [r.analysis.get("allan", {}).get("arw_deg_per_sqrt_h") for r in recs]
        arw = max(a for a in arws if a) if any(arws) else 0.6
        floor = settle + measurement_floor_s(proc_path, arw)
        verdicts = ",".join(str(r.verdict) for r in recs)
        rows.append((n, total, total / n, floor / n, settle, floor - settle, wall, cpu, verdicts))
        print(f"  ... {n} socket(s) done in {wall:.0f} s wall", flush=True)
    pace = "in lockstep" if args.speed is None else f"at {args.speed:g}x"
    print(f"\nprocedure {proc_path.name}, bench {pace}")
    head = (
        f"{'sockets':>7} {'station min':>11} {'per part min':>12} {'bound/part min':>14} "
        f"{'ratio':>6} {'settle min':>10} {'measure min':>11} {'wall s':>7} {'cpu s':>6}  verdicts"
    )
    print(head)
    print("-" * len(head))
    for n, total, per, bound, settle, meas, wall, cpu, verdicts in rows:
        print(
            f"{n:7d} {total / 60:11.1f} {per / 60:12.2f} {bound / 60:14.2f} {per / bound:6.2f} "
            f"{settle / 60:10.1f} {meas / 60:11.1f} {wall:7.1f} {cpu:6.0f}  {verdicts}"
        )
    print("cpu s: the station's and the bench's CPU time (in lockstep the two take turns, so on")
    print("an idle machine the wall time is about the cpu time; on a loaded one it is longer)")
    print(f"run folders in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
