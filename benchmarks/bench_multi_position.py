"""The hand-turned multi-position analysis on simulated sessions: error, k=2 coverage, time,
and agreement with imucal's FerrarisCalibration (when imucal is installed: the test extras).

    python3 benchmarks/bench_multi_position.py [--sessions 300] [--rrw 0.0]

Sessions come from tests/analysis/hand_turned.py (100 Hz, 8 s faces, 4 s rotations of 360 deg,
white noise 0.05 deg/s per sample, faces tilted about 1 deg); `--rrw` adds a bias random walk
(deg/s per sqrt(s)) to see the uncertainties under correlated noise.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from procedures.analysis.multi_position import (  # noqa: E402
    FACES,
    SECTIONS,
    analyze_multi_position,
)
from tests.analysis.hand_turned import (  # noqa: E402
    Session,
    hand_turned_session,
    random_truth,
)


def _imucal(s: Session) -> NDArray[np.float64] | None:
    try:
        import imucal
        from imucal.ferraris_calibration import FerrarisSignalRegions
    except ImportError:
        return None
    regions = {}
    for name in SECTIONS:
        a, b = s.sections[name]
        regions["acc_" + name] = s.accel_mps2[a:b]
        regions["gyr_" + name] = s.gyro_dps[a:b]
    cal = imucal.FerrarisCalibration(grav=9.80665, expected_angle=s.rotation_deg)
    info = cal.compute(FerrarisSignalRegions(**regions), s.sample_rate_hz, "m/s^2", "deg/s")
    m = np.linalg.inv(info.R_g) @ np.linalg.inv(info.K_g)
    return np.concatenate([np.asarray(info.b_g), m.ravel(), np.asarray(info.K_ga).ravel()])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sessions", type=int, default=300)
    ap.add_argument("--rrw", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    z, err, vs_imucal, times = [], [], [], []
    for _ in range(args.sessions):
        truth = random_truth(rng)
        s = hand_turned_session(rng, truth, rrw_dps_per_sqrt_s=args.rrw)
        t0 = time.perf_counter()
        r = analyze_multi_position(s.gyro_dps, s.sections, s.sample_rate_hz,
                                   accel_mps2=s.accel_mps2)
        times.append(time.perf_counter() - t0)
        assert r.g_sensitivity_dps_per_mps2 is not None
        assert r.u_g_sensitivity_dps_per_mps2 is not None
        est = np.concatenate([r.bias_dps, r.matrix.ravel(), r.g_sensitivity_dps_per_mps2.ravel()])
        u = np.concatenate([r.u_bias_dps, r.u_matrix.ravel(),
                            r.u_g_sensitivity_dps_per_mps2.ravel()])
        true = np.concatenate([truth.bias_dps, truth.matrix.ravel(),
                               truth.g_sensitivity.ravel()])
        # with a bias random walk the bias is the faces' average of it: what a static
        # calibration can know, and what the six faces' means estimate
        walk = np.mean([s.bias_walk_dps[slice(*s.sections[f])].mean(axis=0) for f in FACES],
                       axis=0)
        true[0:3] += walk
        z.append((est - true) / u)
        err.append(est - true)
        ref = _imucal(s)
        if ref is not None:
            vs_imucal.append(np.abs(ref - est) / (2 * u))
    zs, es = np.array(z), np.array(err)
    print(f"{args.sessions} sessions, rrw {args.rrw:g} deg/s/sqrt(s)")
    for name, cols in (("b", slice(0, 3)), ("M", slice(3, 12)), ("G", slice(12, 21))):
        cover = float(np.mean(np.abs(zs[:, cols]) <= 2))
        rms = float(np.sqrt(np.mean(es[:, cols] ** 2)))
        print(f"  {name}: k=2 coverage {100 * cover:5.1f} %   std(error/u) "
              f"{float(np.std(zs[:, cols])):.3f}   rms error {rms:.3g}")
    print(f"  analysis time: median {1e3 * float(np.median(times)):.1f} ms per session")
    if vs_imucal:
        v = np.array(vs_imucal)
        print(f"  |ours - imucal| / U(k=2): median {float(np.median(v)):.3f}, "
              f"max {float(v.max()):.3f}  (all within U: {bool(np.all(v <= 1))})")
    else:
        print("  imucal not installed: agreement not measured")


if __name__ == "__main__":
    main()
