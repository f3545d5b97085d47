"""Turn-on to turn-on bias repeatability measured by the station against the bench's truth.

Many simulated parts, each with its own turn-on sigma (drawn here, uniformly over
--sigma-range), run through a short procedure (power on, `turn_on_repeatability` with N
power-ons) on the simulated bench, --sockets parts at a time. For each part: the truth sigma,
the standard deviation of the offsets the bench actually drew at those N power-ons (truth
`turn_on_history_dps`), the station's figure with its k = 2 uncertainty and exact 95 %
interval. Summary: the station's error against the drawn offsets (what the measurement itself
adds: noise, wander), the ratio to the truth sigma, and how often the truth sigma lies within
the k = 2 and the exact 95 % intervals.

    python3 benchmarks/bench_turn_on.py [--parts 32] [--sockets 4] [--speed 100]
                                         [--sigma-range 0.01 0.1] [--seed 1]
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.runtime.record import read_record  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402

PROCEDURE = ROOT / "tests/data/newsteps/turn_on_only.yaml"
NAME = "turn_on_bias_repeatability_dps"


def run_batch(
    parts: list[dict[str, object]], out: Path, speed: float
) -> list[dict[str, float | str]]:
    result, truth = run_simulated(parts, procedure_path=PROCEDURE, out=out, speed=speed)
    rows: list[dict[str, float | str]] = []
    for p in parts:
        s = int(p["socket"])  # type: ignore[call-overload]
        rec = read_record(result.folders[s])
        m = next((m for m in rec.measurements if m.name == NAME), None)
        tor = rec.analysis.turn_on_repeatability.get("run")
        if m is None or m.value is None or tor is None:
            print(f"  {p['serial']}: {rec.verdict} {rec.reason}", flush=True)
            continue
        n = len(tor.biases_dps)
        drawn = truth["sockets"][str(s)]["turn_on_history_dps"][-n:]
        rows.append({
            "serial": str(p["serial"]),
            "sigma": float(p["turn_on_bias_sigma_dps"]),  # type: ignore[arg-type]
            "drawn": float(np.std(drawn, ddof=1)),
            "measured": float(m.value),
            "u_k2": float(m.uncertainty_k2 or math.nan),
            "lo95": float(tor.interval_95_dps[0] or math.nan),
            "hi95": float(tor.interval_95_dps[1] or math.nan),
            "floor": float(tor["noise_floor_dps"]),
        })
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=32)
    ap.add_argument("--sockets", type=int, default=4)
    ap.add_argument("--speed", type=float, default=100.0)
    ap.add_argument("--sigma-range", type=float, nargs=2, default=(0.01, 0.1))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--first-serial", type=int, default=7001)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)  # not the load-time list of unmeasured limits
    rng = np.random.default_rng(args.seed)
    out = Path(tempfile.mkdtemp(prefix="bench-turn-on-"))
    rows: list[dict[str, float | str]] = []
    serial, t0, tried = args.first_serial, time.monotonic(), 0
    while tried < args.parts:
        n = min(args.sockets, args.parts - tried)
        tried += n
        parts: list[dict[str, object]] = [
            {"socket": s, "serial": f"SIM-{serial + s - 1:04d}",
             "turn_on_bias_sigma_dps": float(rng.uniform(*args.sigma_range))}
            for s in range(1, n + 1)
        ]
        serial += n
        rows += run_batch(parts, out, args.speed)
        print(f"  ... {tried} parts run, {len(rows)} measured ({time.monotonic() - t0:.0f} s "
              "wall)", flush=True)
    if not rows:
        print("no part was measured: see the reasons above", file=sys.stderr)
        return 1
    print(f"\n{'serial':<10} {'sigma':>8} {'drawn':>8} {'measured':>9} {'U(k=2)':>8} "
          f"{'95% interval':>19} {'floor':>7}   (deg/s)")
    for r in rows:
        print(f"{r['serial']:<10} {r['sigma']:8.4f} {r['drawn']:8.4f} {r['measured']:9.4f} "
              f"{r['u_k2']:8.4f} [{r['lo95']:7.4f}, {r['hi95']:7.4f}] {r['floor']:7.4f}")
    sigma = np.array([r["sigma"] for r in rows], dtype=float)
    drawn = np.array([r["drawn"] for r in rows], dtype=float)
    meas = np.array([r["measured"] for r in rows], dtype=float)
    u_k2 = np.array([r["u_k2"] for r in rows], dtype=float)
    lo, hi = (np.array([r[k] for r in rows], dtype=float) for k in ("lo95", "hi95"))
    err = meas - drawn
    print(f"\n{len(rows)} of {tried} parts measured, 8 power-ons each (wall "
          f"{time.monotonic() - t0:.0f} s)")
    print(f"station figure - std of the drawn offsets: mean {np.mean(err):+.5f}, "
          f"rms {np.sqrt(np.mean(err**2)):.5f} deg/s (noise floor mean "
          f"{np.mean([r['floor'] for r in rows]):.5f})")
    print(f"station figure / truth sigma: mean {np.mean(meas / sigma):.3f}, "
          f"sd {np.std(meas / sigma, ddof=1):.3f} (c4(8) = 0.965 expected from N = 8 alone)")
    print(f"truth sigma within figure +/- U(k=2): {np.mean(np.abs(meas - sigma) <= u_k2):.1%}; "
          f"within the exact 95 % interval: {np.mean((lo <= sigma) & (sigma <= hi)):.1%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
