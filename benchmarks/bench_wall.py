"""Wall time of the full 2 x 2 procedure on the simulated bench in lockstep, and lockstep's
determinism beside a CPU-bound process.

For each socket count: one load of parts through config/procedures/eol-rate-table.yaml on a
fresh lockstep bench; prints the station time of the load (record.json timings.total), the
wall time, the CPU time of the station and the bench, and the verdicts. Then the first socket
count once more with a CPU-bound process beside it (niced, as the lockstep test does): the
station time must agree within 1 % (in lockstep it is physics time) and every measurement of
every part must be the same value.

    python3 benchmarks/bench_wall.py [--sockets 8 32] [--no-hog] [--procedure PATH]
                                     [--profile DIR]

--profile DIR runs both processes under cProfile (the station in-process, the bench through
GYROCAL_BENCH_PROFILE) and writes station-N.prof and bench-N.prof there, with a summary of
each; the profiled figures are slower than unprofiled ones.

The issue's targets (issue 15): 8 sockets in at most 30 s of wall time, 32 in at most 2 min.
The wall time includes starting the bench process and the station's imports; on a machine
shared with other work it is longer than the CPU time (the two processes take turns).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.runtime.record import read_record  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402

HOG = "import os\nos.nice(5)\nwhile True:\n    pass\n"


def cpu_s() -> float:
    """CPU seconds of this process (the station) and its waited children (the bench)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def one_load(
    n: int, proc_path: Path, out: Path, profile_dir: Path | None = None
) -> dict[str, Any]:
    """One load of `n` parts in lockstep: station s, wall s, cpu s, verdicts, values."""
    first = 9000 + 100 * (n // 8)
    parts = [{"socket": s, "serial": f"SIM-{first + s:04d}"} for s in range(1, n + 1)]
    profiler = None
    if profile_dir is not None:
        profile_dir.mkdir(parents=True, exist_ok=True)
        os.environ["GYROCAL_BENCH_PROFILE"] = str(profile_dir / f"bench-{n}.prof")
        profiler = cProfile.Profile()
        profiler.enable()
    w0, c0 = time.monotonic(), cpu_s()
    try:
        result, truth = run_simulated(parts, procedure_path=proc_path, out=out)
    finally:
        if profiler is not None:
            profiler.disable()
            profiler.dump_stats(profile_dir / f"station-{n}.prof")  # type: ignore[operator]
            os.environ.pop("GYROCAL_BENCH_PROFILE", None)
    wall, cpu = time.monotonic() - w0, cpu_s() - c0
    recs = [read_record(result.folders[s]) for s in sorted(result.folders)]
    values = {
        r.dut.serial: [(m.name, m.condition, m.value) for m in r.measurements] for r in recs
    }
    lost = sum(int(v.get("frames_dropped", 0)) for v in truth["sockets"].values())
    return {
        "sockets": n,
        "station_s": max(float(r.timings.get("total", 0.0)) for r in recs),
        "wall_s": wall,
        "cpu_s": cpu,
        "verdicts": [str(r.verdict) for r in recs],
        "values": values,
        "frames_dropped": lost,
    }


def print_profile(path: Path, top: int = 25) -> None:
    """The `top` functions of a profile by their own time, and by cumulative time."""
    if not path.exists():
        print(f"(no profile at {path})")
        return
    for key in ("tottime", "cumulative"):
        buf = io.StringIO()
        pstats.Stats(str(path), stream=buf).strip_dirs().sort_stats(key).print_stats(top)
        print(f"--- {path.name} by {key}")
        print(buf.getvalue())


def print_row(label: str, row: dict[str, Any]) -> None:
    verdicts = row["verdicts"]
    passed = sum(v == "PASS" for v in verdicts)
    print(
        f"{label:<22} {row['sockets']:7d} {row['station_s'] / 60:11.1f} {row['wall_s']:7.1f} "
        f"{row['cpu_s']:6.1f} {passed:3d}/{len(verdicts):<3d} {row['frames_dropped']:6d}",
        flush=True,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sockets", type=int, nargs="+", default=[8, 32])
    ap.add_argument("--no-hog", action="store_true", help="skip the run beside a CPU hog")
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-rate-table.yaml"))
    ap.add_argument("--profile", metavar="DIR", help="cProfile both processes into DIR")
    args = ap.parse_args()
    profile_dir = Path(args.profile) if args.profile else None
    proc_path = Path(args.procedure)
    out = Path(tempfile.mkdtemp(prefix="bench-wall-"))
    print(f"procedure {proc_path.name}, bench in lockstep; run folders in {out}")
    head = (
        f"{'run':<22} {'sockets':>7} {'station min':>11} {'wall s':>7} {'cpu s':>6} "
        f"{'pass':>7} {'lost':>6}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for n in args.sockets:
        rows.append(one_load(n, proc_path, out / f"quiet-{n}", profile_dir))
        print_row("quiet", rows[-1])
        if profile_dir is not None:
            for name in (f"station-{n}.prof", f"bench-{n}.prof"):
                print_profile(profile_dir / name)
    if args.no_hog or profile_dir is not None:
        return 0
    quiet = rows[0]
    hog = subprocess.Popen([sys.executable, "-c", HOG])
    try:
        busy = one_load(quiet["sockets"], proc_path, out / "hog")
    finally:
        hog.kill()
        hog.wait()
    print_row("beside a CPU hog", busy)
    diff = abs(busy["station_s"] - quiet["station_s"]) / quiet["station_s"]
    same = busy["values"] == quiet["values"]
    print(
        f"\nlockstep determinism: station time {quiet['station_s']:.1f} s quiet, "
        f"{busy['station_s']:.1f} s beside the hog ({100 * diff:.2f} %, limit 1 %); "
        f"every measurement the same value: {'yes' if same else 'NO'}"
    )
    print("cpu s: the station's and the bench's CPU time together")
    return 0 if diff <= 0.01 and same else 1


if __name__ == "__main__":
    sys.exit(main())
