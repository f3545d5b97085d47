"""Three-axis calibration: coverage and error of b, M, G (and the per-axis temperature and
supply coefficients) over many simulated parts, and the station time per part.

Each part's truth is drawn from the bench's three-axis population (drivers/sim/gyro3.py,
`resolve_three_axis`, per serial number); its windows follow the station's orientation plan
(procedures/runtime/orientation_plan.py: six faces at the first condition, one face per axis at the
others; at each face a static window and +r/-r table plateaus) and the contract's model
raw = M^-1 D w + b + G a, with white noise on each window's mean from the part's angle random
walk over the dwell. The fit is procedures/analysis/three_axis.py; the station time is the
plan's estimate from the dwell, turn and table times below.

With `--full-runs N`, N simulated three-axis parts instead go through the station itself on
the simulated bench (loads of up to 8, lockstep, distinct serials): the eol-three-axis
procedure, its records' b, M, G and coefficients against the bench's truth, and the station
time per load and per part.

    python3 benchmarks/bench_three_axis.py [--parts 300] [--seed 1]
    python3 benchmarks/bench_three_axis.py --full-runs 24 [--load 8] [--procedure FILE]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.orientation import gravity_specific_force_mps2, up_vector  # noqa: E402
from drivers.sim.config import ThreeAxisSpec  # noqa: E402
from drivers.sim.gyro3 import resolve_three_axis  # noqa: E402
from procedures.analysis.three_axis import Window, fit_three_axis  # noqa: E402
from procedures.runtime.orientation_plan import plan, turns  # noqa: E402

CONDITIONS = ((25.0, 4.75), (25.0, 5.25), (45.0, 5.25), (45.0, 4.75))
RATE_DPS = 100.0
STATIC_S = 10.0  # dwell per window, station seconds
ARW_DEG_PER_SQRT_H = 0.5
OPERATOR_TURN_S = 1.0 + 3.0 + 1.0  # reaction, turn, accelerometer confirmation
TABLE_SETTLE_S = 3.0  # accelerate/settle to each plateau
NAMES = ("bias_dps", "matrix", "g_sensitivity_dps_per_mps2", "bias_temp_coeff_dps_per_c",
         "bias_supply_coeff_dps_per_v", "scale_temp_coeff_per_c", "scale_supply_coeff_per_v")


def part_windows(truth: dict[str, np.ndarray], rng: np.random.Generator) -> list[Window]:
    u = ARW_DEG_PER_SQRT_H / 60.0 / np.sqrt(STATIC_S)
    out = []
    for k, faces in enumerate(plan(len(CONDITIONS), "+z")):
        temp_c, supply_v = CONDITIONS[k]
        die_c = temp_c + 2.5 + rng.normal(0.0, 0.3)
        dt, dv = die_c - 25.0, supply_v - 5.0
        s = np.linalg.inv(truth["matrix"]) @ np.diag(
            1 + truth["scale_temp_coeff_per_c"] * dt + truth["scale_supply_coeff_per_v"] * dv)
        b = (truth["bias_dps"] + truth["bias_temp_coeff_dps_per_c"] * dt
             + truth["bias_supply_coeff_dps_per_v"] * dv)
        for face in faces:
            a = gravity_specific_force_mps2(face) + rng.normal(0.0, 0.003 / 30, 3)
            for r in (0.0, RATE_DPS, -RATE_DPS):
                raw = s @ (r * up_vector(face)) + b + truth["g_sensitivity_dps_per_mps2"] @ a
                out.append(Window(face, r, tuple(raw + rng.normal(0.0, u, 3)), (u, u, u),
                                  tuple(a), die_c, supply_v, f"c{k}"))
    return out


def station_time_s() -> tuple[float, int]:
    runs = plan(len(CONDITIONS), "+z")
    n_turns = turns([f for faces in runs for f in faces], "+z")
    n_faces = sum(len(f) for f in runs)
    per_face = STATIC_S + 2 * (TABLE_SETTLE_S + STATIC_S)
    return n_turns * OPERATOR_TURN_S + n_faces * per_face, n_turns


def full_runs(n_parts: int, load: int, procedure: Path, seed: int) -> None:
    """N parts through the station on the bench; coverage, error/U and station time."""
    import tempfile

    from station.sim_run import run_simulated

    inside: dict[str, list[bool]] = {n: [] for n in NAMES}
    z2: dict[str, list[float]] = {n: [] for n in NAMES}
    times: list[float] = []
    verdicts: dict[str, int] = {}
    t0 = time.perf_counter()
    for first in range(0, n_parts, load):
        socks = range(1, min(load, n_parts - first) + 1)
        parts = [{"socket": s, "serial": f"IMU-{seed % 10}{first + s:03d}", "three_axis": {}}
                 for s in socks]
        with tempfile.TemporaryDirectory(prefix="bench-3axis-") as out:
            result, truth = run_simulated(parts, procedure_path=procedure, out=Path(out))
            times.append(result.station_time_s)
            for s in socks:
                verdicts[str(result.verdicts[s])] = verdicts.get(str(result.verdicts[s]), 0) + 1
                record = _read_record(result.folders[s])
                cal = record.get("calibration_three_axis")
                if not cal:
                    continue
                params = truth["sockets"][str(s)]["parameters"]
                for n in NAMES:
                    want = np.asarray(params[n], dtype=float)
                    got = np.asarray(cal[n]["value"], dtype=float)
                    u_k2 = np.asarray(cal[n]["uncertainty_k2"], dtype=float)
                    e = np.abs(got - want).ravel()
                    inside[n].extend((e <= u_k2.ravel()).tolist())
                    z2[n].extend(((e / (u_k2.ravel() / 2)) ** 2).tolist())
        print(f"  load of {len(socks)}: station {times[-1] / 60:.1f} min "
              f"({time.perf_counter() - t0:.0f} s wall so far)", flush=True)
    print(f"{n_parts} parts through {procedure.name} on the bench (lockstep), "
          f"verdicts {verdicts}")
    print(f"{'coefficient':32s} {'coverage':>9s} {'rms(err/u)':>11s}  (k=2 coverage target "
          "93-97 %; err/u at k=1 should be about 1)")
    for n in NAMES:
        if inside[n]:
            print(f"{n:32s} {100 * np.mean(inside[n]):8.1f}% "
                  f"{np.sqrt(np.mean(z2[n])):11.2f}   ({len(inside[n])} values)")
    per_load = float(np.mean(times))
    print(f"station time per load {per_load / 60:.1f} min (mean of {len(times)}), "
          f"per part {per_load / 60 / load:.1f} min at {load} per load")


def _read_record(folder: Path) -> dict[str, Any]:
    import json

    return dict(json.loads((folder / "record.json").read_text()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--full-runs", type=int, default=0, metavar="N",
                    help="N parts through the station on the simulated bench instead")
    ap.add_argument("--load", type=int, default=8, help="parts per load (--full-runs)")
    ap.add_argument("--procedure", type=Path,
                    default=ROOT / "config/procedures/eol-three-axis.yaml")
    args = ap.parse_args()
    if args.full_runs:
        full_runs(args.full_runs, args.load, args.procedure, args.seed)
        return
    rng = np.random.default_rng(args.seed)
    inside: dict[str, list[bool]] = {n: [] for n in NAMES}
    err: dict[str, list[float]] = {n: [] for n in NAMES}
    u2: dict[str, list[float]] = {n: [] for n in NAMES}
    t0 = time.perf_counter()
    for i in range(args.parts):
        three = resolve_three_axis(f"IMU-{i:04d}-{args.seed}", ThreeAxisSpec())
        truth = {k: np.asarray(v, dtype=float) for k, v in three.as_truth().items() if k != "axes"}
        cal = fit_three_axis(part_windows(truth, rng))
        for n in NAMES:
            e = np.abs(cal.value(n) - truth[n]).ravel()
            inside[n].extend((e <= cal.uncertainty_k2(n).ravel()).tolist())
            err[n].extend(e.tolist())
            u2[n].extend(cal.uncertainty_k2(n).ravel().tolist())
    fit_s = (time.perf_counter() - t0) / args.parts
    print(f"{args.parts} parts, {len(CONDITIONS)} conditions, fit {fit_s * 1e3:.1f} ms/part")
    print(f"{'coefficient':32s} {'coverage':>9s} {'rms error':>11s} {'median U(k=2)':>14s}")
    for n in NAMES:
        rms = float(np.sqrt(np.mean(np.square(err[n]))))
        print(f"{n:32s} {100 * np.mean(inside[n]):8.1f}% {rms:11.3g} {np.median(u2[n]):14.3g}")
    total_s, n_turns = station_time_s()
    print(f"station time per part (plan estimate, chamber time excluded): {total_s:.0f} s, "
          f"{n_turns} operator turns")


if __name__ == "__main__":
    main()
