"""Detection limit of sensor_lag through full station runs (prints its figures; not a test).

For each time constant scanned: population parts (each its own serial, so its own noise and
first-order terms) with only `effects: {sensor_lag: {tau_s: TAU}}` added are loaded eight to
a bench, `station run --sim` runs the shortened end-of-line procedure of the station tests
(tests/model/data/eol-discrepancy.yaml: 2 temperatures x 2 supplies, 8 rates, stop method,
4 table positions, 100 Hz, real protocols, hardware sync) on all eight at once, and the
workflow runs on each part's run folder from `first_order`. Reported per tau: the fraction
of parts where sensor_lag is named first (first entry of effects_added), the 5-sigma tau
(the tau whose signature, after projecting out first_order, has chi^2 = 25 on that record's
measured noise: bench_discrepancy.five_sigma_on on the station trajectory), the fitted tau
and its uncertainty, and the workflow time per run folder. The detection limit is the
smallest scanned tau named first in at least 95 % of parts.

    python3 benchmarks/bench_discrepancy_station.py [--parts-per-value 8]
                                                    [--taus 0.0001,0.00015,0.0002,0.0003]
                                                    [--speed 100] [--out DIR]

With --thermal (issue 29): the honest thermal bench instead. Parts on the default honest
bench through both shipped procedures (config/procedures/eol-ramp.yaml and
eol-rate-table.yaml), the same parts with the thermal physics off (the floor to reach), and
on the ramp a bench with only the gradient bias and one with only the hysteresis
(tests/model/thermal_station.py BENCHES). The workflow runs from `first_order` on each run
folder; one row per folder (the thermal-off folders too: the null): the part's drawn thermal
effects (the truth), each effect's size on the folder (z against the workflow's own test, its
gap / floor, a star where it is expected to be named: tests/model/thermal_truth.py), the
effects named with their regressors, the gap before and after, the record's floor and the
floor of the same part without the effects, and whether it matches the truth.

    python3 benchmarks/bench_discrepancy_station.py --thermal [--parts 6] [--out DIR] [--markdown]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "tests" / "model"))

from bench_discrepancy import five_sigma_on  # noqa: E402

from procedures.model.discrepancy import run_discrepancy  # noqa: E402
from procedures.model.gyro_model import first_order_model  # noqa: E402
from procedures.model.run_folder import load_data  # noqa: E402
from procedures.runtime.record import read_record  # noqa: E402

PROCEDURE = ROOT / "tests" / "model" / "data" / "eol-discrepancy.yaml"
SOCKETS = 8
EFFECT = "sensor_lag"


@dataclass(frozen=True)
class PartResult:
    serial: str
    named: list[str]
    five_sigma_s: float
    tau_s: float  # fitted (final model), nan if sensor_lag was not named
    tau_sigma_s: float
    workflow_s: float
    samples: int


def station_run(
    workdir: Path, tau_s: float, serials: list[str], speed: float
) -> tuple[dict[str, Path], dict[str, str]]:
    """One `station run --sim` with these parts: the run folder of each part that finished
    (PASS or FAIL), and the reason for each part that did not (ERROR: left out)."""
    parts = [{"socket": i + 1, "serial": s, "effects": {EFFECT: {"tau_s": tau_s}}}
             for i, s in enumerate(serials)]
    cfg = workdir / "sim.yaml"
    cfg.write_text(yaml.safe_dump({"speed": speed, "fixture": {"sockets": len(parts)},
                                   "parts": parts}))
    out = workdir / "runs"
    args = [sys.executable, "-m", "station", "run", "--sim", "--sim-config", str(cfg),
            "--procedure", str(PROCEDURE), "--out", str(out)]
    for s in serials:
        args += ["--dut", s]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(args, capture_output=True, text=True, env=env, cwd=ROOT, timeout=1800)
    folders: dict[str, Path] = {}
    errors: dict[str, str] = {}
    for s in serials:
        found = sorted(out.glob(f"*_{s}"))
        verdict = read_record(found[-1]).verdict if found else "no run folder"
        if verdict in ("PASS", "FAIL"):
            folders[s] = found[-1]
        else:
            errors[s] = verdict
    # exit 0 PASS, 1 FAIL, 2 error or abort (one part's ERROR is enough)
    if done.returncode not in (0, 1, 2) or not folders:
        raise RuntimeError(f"station run failed ({done.returncode}): "
                           f"{(done.stdout + done.stderr)[-2000:]}")
    for s, why in errors.items():
        line = next((ln for ln in done.stdout.splitlines() if s in ln and "ERROR" in ln), "")
        print(f"  {s}: {why}, left out: {line.strip()}", flush=True)
    return folders, errors


def analyse(folder: Path, serial: str) -> PartResult:
    traj = load_data(folder, dut=serial)
    start = first_order_model()
    t0 = time.perf_counter()
    res = run_discrepancy(traj, start)
    workflow_s = time.perf_counter() - t0
    lag = res.final_model.effects.get(EFFECT)
    return PartResult(
        serial=serial,
        named=res.effects_added,
        five_sigma_s=five_sigma_on(traj, EFFECT, start),
        tau_s=float(lag["tau_s"]) if lag else math.nan,
        tau_sigma_s=float(res.final_model.uncertainties.get(f"{EFFECT}.tau_s", math.nan))
        if lag else math.nan,
        workflow_s=workflow_s,
        samples=traj.n,
    )


def _median(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return statistics.median(finite) if finite else math.nan


def _ms(v: float) -> str:
    return f"{v * 1e3:.3g}" if math.isfinite(v) else "-"


def thermal_grid(base: Path, parts: int, markdown: bool = False) -> None:
    """The per-folder table of the honest thermal bench (see the module's docstring)."""
    import thermal_station as ts

    serials = [f"SIM-{2931 + i}" for i in range(parts)]
    runs = [(proc, bench) for proc in ts.PROCEDURES for bench in ("ideal", "honest")]
    runs += [("ramp", "gradient-only"), ("ramp", "hysteresis-only")]
    floors: dict[tuple[str, str], float] = {}
    rows, truths, wrong = [], {}, 0
    t_start = time.perf_counter()
    for proc, bench in runs:
        t0 = time.perf_counter()
        folders = ts.station_run(base / f"{proc}-{bench}", bench, proc, serials)
        print(f"{proc} on the {bench} bench: {len(folders)}/{parts} run folders "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        for s, folder in folders.items():
            truths[s + bench] = ts.truth(s, bench)
            answer = ts.analyse(folder, s, truths[s + bench])
            if bench == "ideal":
                floors[(proc, s)] = answer.floor_dps
            row = ts.FolderResult(s, proc, bench, answer, floors.get((proc, s), math.nan))
            problems = ts.verdict(row, truths[s + bench])
            wrong += bool(problems)
            rows.append(row)
            print(f"  {s}: {'; '.join(problems) or 'matches the truth'}", flush=True)
    print("\n" + ts.table(rows, truths))
    if markdown:
        print("\n" + ts.markdown(rows, truths))
    print(f"\n{len(rows) - wrong}/{len(rows)} folders match the truth (every named effect's "
          "regressors within a drawn effect's variables, every effect of z at least the "
          "expected threshold named, gap after <= 1.5 x the floor of the same part without "
          "the thermal physics; ideal rows: the null, nothing to name)")
    z = sorted({round(r.answer.z_expected, 2) for r in rows})
    print(f"expected threshold z* {', '.join(map(str, z))} (power {ts.tt.POWER} at the first "
          f"Holm step of a library term); wall time {time.perf_counter() - t_start:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--thermal", action="store_true",
                    help="the honest thermal bench's per-folder table instead (issue 29)")
    ap.add_argument("--parts", type=int, default=6, help="parts per run with --thermal")
    ap.add_argument("--markdown", action="store_true",
                    help="with --thermal, the table in Markdown too")
    ap.add_argument("--parts-per-value", type=int, default=8,
                    help="parts per tau (eight per station run)")
    ap.add_argument("--taus", default="0.0001,0.00015,0.0002,0.0003",
                    help="time constants to scan, seconds, comma-separated")
    ap.add_argument("--speed", type=float, default=100.0, help="simulated bench speed factor")
    ap.add_argument("--out", type=Path, help="keep the run folders here (default: a temp dir)")
    args = ap.parse_args()
    if args.thermal and not 1 <= args.parts <= SOCKETS:
        ap.error(f"--parts: 1 to {SOCKETS} (one station run, one socket each)")
    if args.thermal:
        with tempfile.TemporaryDirectory() as tmp:
            thermal_grid(args.out or Path(tmp), args.parts, args.markdown)
        return
    taus = [float(t) for t in args.taus.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        base = args.out or Path(tmp)
        rows = []
        for i, tau in enumerate(taus):
            serials = [f"SIM-5{i}{k:02d}" for k in range(args.parts_per_value)]
            results: list[PartResult] = []
            station_s = 0.0
            errors = 0
            for b in range(0, len(serials), SOCKETS):
                batch = serials[b : b + SOCKETS]
                workdir = base / f"tau{i}_{b // SOCKETS}"
                workdir.mkdir(parents=True, exist_ok=True)
                t0 = time.perf_counter()
                folders, errored = station_run(workdir, tau, batch, args.speed)
                station_s += time.perf_counter() - t0
                errors += len(errored)
                for s in folders:
                    r = analyse(folders[s], s)
                    results.append(r)
                    print(f"  tau {_ms(tau)} ms {s}: named {r.named}, fitted {_ms(r.tau_s)} "
                          f"+- {_ms(r.tau_sigma_s)} ms, 5 sigma {_ms(r.five_sigma_s)} ms, "
                          f"workflow {r.workflow_s:.2f} s ({r.samples} samples)", flush=True)
            first = sum(bool(r.named) and r.named[0] == EFFECT for r in results)
            rows.append((tau, first, len(results), results, station_s, errors))
    print(f"\nsensor_lag through full station runs ({PROCEDURE.name}, speed {args.speed:g}, "
          f"{SOCKETS} parts per run, {args.parts_per_value} parts per tau, population parts, "
          "start first_order, alpha 0.01 Holm)")
    print(f"{'tau ms':>7} {'named first':>12} {'5 sigma ms':>11} {'fitted ms':>10} "
          f"{'+- ms':>7} {'workflow s':>11} {'station s':>10} {'errors':>6}")
    limit = math.inf
    for tau, first, n, results, station_s, errors in rows:
        named = [r for r in results if r.named and r.named[0] == EFFECT]
        print(f"{_ms(tau):>7} {f'{first}/{n}':>12} "
              f"{_ms(_median([r.five_sigma_s for r in results])):>11} "
              f"{_ms(_median([r.tau_s for r in named])):>10} "
              f"{_ms(_median([r.tau_sigma_s for r in named])):>7} "
              f"{_median([r.workflow_s for r in results]):>11.2f} "
              f"{station_s / math.ceil(args.parts_per_value / SOCKETS):>10.0f} {errors:>6}")
    for tau, first, n, *_ in sorted(rows, key=lambda row: -row[0]):  # from the largest down
        if n == 0 or first < 0.95 * n:
            break
        limit = tau
    all_5s = _median([r.five_sigma_s for *_, results, _, _ in rows for r in results])
    print(f"\nsmallest tau named first in >= 95 % of parts (and every larger one): "
          f"{_ms(limit)} ms; median 5-sigma tau {_ms(all_5s)} ms; "
          f"ratio {limit / all_5s:.2g}" if math.isfinite(limit) else
          f"\nno scanned tau named first in >= 95 % of parts; median 5-sigma tau "
          f"{_ms(all_5s)} ms")
    print("(named first: of the parts whose run finished PASS or FAIL; errors: parts whose "
          "run ended in ERROR, left out; workflow s: median per run folder; station s: wall "
          "time per station run)")


if __name__ == "__main__":
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # small dense solves: see discrepancy.py
        main()
