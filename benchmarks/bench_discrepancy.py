"""Benchmark of the model-discrepancy workflow (prints its figures; not a timed test).

For each catalog effect: the smallest magnitude named correctly (named first) in at least
95 % of trials at the documented false-alarm setting (alpha = 0.01 per iteration, Holm),
against the magnitude at which the effect's signature is 5 sigma above the noise floor for
that run (the whitened signature left after projecting out the starting model has
chi^2 = 25). And the time the workflow takes on a full-length run.

    python3 benchmarks/bench_discrepancy.py [--trials 20] [--effects k2_quadratic,...]
                                            [--timing-only] [--run-folder DIR]
                                            [--library-kinds KIND,...] [--null-trials N]
                                            [--null-profile RAMPED|RAMPED_UPDOWN]
                                            [--station-run] [--simulate] [--sim-speed X]

Library term kinds (effects outside the catalog, synth_gyro.BEYOND_CATALOG, RAMPED profile:
SHORT with a 0.2 C/s chamber ramp; RAMPED3, plateaus at three temperatures, for the scale
quadratic in temperature; RAMPED_UPDOWN, up to 55 C and back to 25 C, for the hysteresis:
synth_gyro.PROFILE_FOR_KIND; `first_order` on a realistic part):
"named" is a library term named first with the kind's base variables; its 5-sigma magnitude
comes from the generator's own signature (the same seed with and without the effect).
`--null-trials`: the false-alarm rate with the library on (anything named or not separable
on a part with no hidden effect, RAMPED profile).

Time per run on a full run folder: `--run-folder DIR`, or `--station-run` (a full run of the
default procedure made on the simulated bench first); with `--simulate`, also the time of
`station discrepancy --simulate` (two twin station runs and the comparison) and its two
simulation gaps against their noise floor.

Data: the independent test-side generator (tests/model/synth_gyro.py), short records
(SHORT profile: 4 rates, 2 temperatures x 2 supplies, 50 Hz) for the detection figures and
the full profile (8 rates, 100 Hz, ~14 min) for the timing. First-order effects start from
`base` on a part with no other terms; the others from `first_order` on a realistic part.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "model"))

from helpers_model import as_trajectory  # noqa: E402
from synth_gyro import (  # noqa: E402
    BEYOND_CATALOG,
    FIRST_ORDER_EFFECTS,
    FIRST_ORDER_REALISTIC,
    PROFILE_FOR_KIND,
    RAMPED,
    RAMPED_UPDOWN,
    REALISTIC_EFFECTS,
    SHORT,
    Part,
    Profile,
    generate,
    realistic_part,
)

from procedures.model import effects as fx  # noqa: E402
from procedures.model.blocks import make_blocks  # noqa: E402
from procedures.model.discrepancy import measure_record_noise, run_discrepancy  # noqa: E402
from procedures.model.fit import Fitter  # noqa: E402
from procedures.model.gyro_model import GyroModel, base_model, first_order_model  # noqa: E402
from procedures.model.trajectory import Trajectory  # noqa: E402

# the parameter scanned per effect (its "magnitude")
MAGNITUDE_PARAM = {
    **{e: p for e, p in FIRST_ORDER_EFFECTS.items()},
    "k2_quadratic": "k2_per_dps",
    "k3_cubic": "k3_per_dps2",
    "scale_asymmetry": "asymmetry",
    "g_sensitivity_tilt": "g_sens_dps_per_g",
    "sensor_lag": "tau_s",
    "warmup_drift": "amplitude_dps",
}
FACTORS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)


def nominal(effect: str) -> float:
    if effect in FIRST_ORDER_EFFECTS:
        return FIRST_ORDER_REALISTIC[FIRST_ORDER_EFFECTS[effect]]
    return REALISTIC_EFFECTS[effect][MAGNITUDE_PARAM[effect]]


def make_part(effect: str, magnitude: float) -> tuple[Part, GyroModel]:
    name = MAGNITUDE_PARAM[effect]
    if effect in FIRST_ORDER_EFFECTS:
        return Part().with_effect(effect, **{name: magnitude}), base_model()
    return realistic_part().with_effect(effect, **{name: magnitude}), first_order_model()


def five_sigma_magnitude(effect: str, seed: int, profile: Profile) -> float:
    """Magnitude whose signature, after projecting out the starting model, is 5 sigma."""
    _, start = make_part(effect, nominal(effect))
    part = Part() if effect in FIRST_ORDER_EFFECTS else realistic_part()  # effect absent
    return five_sigma_on(as_trajectory(generate(part, seed, profile)), effect, start)


def five_sigma_on(traj: Trajectory, effect: str, start: GyroModel) -> float:
    """Magnitude of `effect` whose signature on `traj`, after projecting out the starting
    model, has chi^2 = 25 on the record's noise (measured as the workflow measures it); the
    signature is taken at the realistic magnitude and scaled linearly."""
    blocks = make_blocks(traj)
    fitter = Fitter(traj, blocks, measure_record_noise(traj, blocks, start)[0])
    m0 = nominal(effect)
    params = {**REALISTIC_EFFECTS.get(effect, {}), MAGNITUDE_PARAM[effect]: m0}
    with_effect = GyroModel(effects={effect: {k: v for k, v in params.items()
                                              if k in fx.CATALOG[effect].params}})
    plain = GyroModel()
    signature = blocks.mean(with_effect.predict(traj) - plain.predict(traj))
    s_white = fitter._whiten(signature)
    structure = {e: fx.nonlinear_of(e, p) for e, p in start.effects.items()}
    terms = ["bias", "scale", *structure]
    x = fitter._whiten(np.concatenate([fitter._block_columns(e, structure.get(e, {}))
                                       for e in terms], axis=1))
    q, _ = np.linalg.qr(x)
    resid = s_white - q @ (q.T @ s_white)
    chi = float(np.linalg.norm(resid))
    return m0 * 5.0 / chi if chi > 0 else math.inf


def detection_rate(effect: str, magnitude: float, trials: int, profile: Profile) -> float:
    hits = misses = 0
    for seed in range(trials):
        part, start = make_part(effect, magnitude)
        res = run_discrepancy(as_trajectory(generate(part, 7000 + seed, profile)), start)
        ok = bool(res.effects_added) and res.effects_added[0] == effect
        hits += ok
        misses += not ok
        if misses > 0.05 * trials:  # 95 % can no longer be reached: stop early
            return hits / (hits + misses)
    return hits / trials


def smallest_detected(effect: str, trials: int, profile: Profile) -> tuple[float, list[str]]:
    m0 = nominal(effect)
    log = []
    for f in FACTORS:
        rate = detection_rate(effect, f * m0, trials, profile)
        log.append(f"{f:g}x:{rate:.2f}")
        if rate >= 0.95:
            return f * m0, log
    return math.inf, log


def timing(profile: Profile, repeats: int = 2) -> float:
    traj = as_trajectory(generate(realistic_part().with_effect("k2_quadratic"), 1, profile))
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        run_discrepancy(traj, first_order_model())
        best = min(best, time.perf_counter() - t0)
    print(f"workflow time, full generator run ({traj.n} samples, "
          f"{traj.time_s[-1] - traj.time_s[0]:.0f} s of data, first_order + k2 hidden): "
          f"{best:.2f} s (best of {repeats})")
    return best


def library_named(kind: str, magnitude: float, seed: int) -> bool:
    name = next(iter(BEYOND_CATALOG[kind][1]))
    part = realistic_part().with_effect(kind, **{name: magnitude})
    res = run_discrepancy(as_trajectory(generate(part, seed, PROFILE_FOR_KIND[kind])),
                          first_order_model())
    return bool(res.iterations) and res.iterations[0].effect.startswith("lib_") and (
        set(res.iterations[0].regressors) == BEYOND_CATALOG[kind][0])


def library_five_sigma(kind: str, seed: int) -> float:
    """Magnitude of a generator-side kind whose signature (same seed with minus without the
    effect), after projecting out first_order, has chi^2 = 25 on the record's noise."""
    name, m0 = next(iter(BEYOND_CATALOG[kind][1].items()))
    profile = PROFILE_FOR_KIND[kind]
    plain = as_trajectory(generate(realistic_part(), seed, profile))
    with_fx = generate(realistic_part().with_effect(kind), seed, profile)
    blocks = make_blocks(plain)
    start = first_order_model()
    fitter = Fitter(plain, blocks, measure_record_noise(plain, blocks, start)[0])
    signature = blocks.mean(np.asarray(with_fx["gyro_dps"]) - plain.gyro_dps)
    structure = {e: fx.nonlinear_of(e, p) for e, p in start.effects.items()}
    x = fitter.whiten(np.concatenate([fitter._block_columns(e, structure.get(e, {}))
                                      for e in ["bias", "scale", *structure]], axis=1))
    q, _ = np.linalg.qr(x)
    s_white = fitter.whiten(signature)
    chi = float(np.linalg.norm(s_white - q @ (q.T @ s_white)))
    return m0 * 5.0 / chi if chi > 0 else math.inf


def library_table(kinds: list[str], trials: int) -> None:
    print(f"\nlibrary term kinds, {trials} trials per magnitude, RAMPED profile (RAMPED3, "
          "plateaus at three temperatures, for scale_temperature_quadratic; RAMPED_UPDOWN "
          "for bias_temperature_hysteresis), first_order")
    print(f"{'kind':28s} {'param':20s} {'95% named':>10s} {'5 sigma':>10s} {'ratio':>6s}")
    for kind in kinds:
        name, m0 = next(iter(BEYOND_CATALOG[kind][1].items()))
        m95, log = math.inf, []
        for f in FACTORS:
            hits = misses = 0
            for seed in range(trials):
                ok = library_named(kind, f * m0, 8000 + seed)
                hits, misses = hits + ok, misses + (not ok)
                if misses > 0.05 * trials:
                    break
            rate = hits / (hits + misses)
            log.append(f"{f:g}x:{rate:.2f}")
            if rate >= 0.95:
                m95 = f * m0
                break
        m5 = library_five_sigma(kind, 1)
        print(f"{kind:28s} {name:20s} {m95:10.3g} {m5:10.3g} {m95 / m5:6.2f}   "
              f"[{' '.join(log)}]", flush=True)


NULL_PROFILES = {"RAMPED": RAMPED, "RAMPED_UPDOWN": RAMPED_UPDOWN}


def null_rate(trials: int, profile: str = "RAMPED") -> None:
    """RAMPED_UPDOWN (up to the hot temperature and back): the temperature direction
    (hysteresis terms) is among the candidates there."""
    alarms = []
    for seed in range(trials):
        traj = as_trajectory(generate(realistic_part(), 9000 + seed, NULL_PROFILES[profile]))
        res = run_discrepancy(traj, first_order_model())
        if res.effects_added or res.not_separable:
            alarms.append((9000 + seed, res.effects_added))
    print(f"false alarms with the library on ({profile}, first_order, realistic part): "
          f"{len(alarms)} of {trials} ({100 * len(alarms) / trials:.1f} %) {alarms}")


DEFAULT_PROCEDURE = ROOT / "config" / "procedures" / "eol-rate-table.yaml"
HIDDEN_ANGLE_2ND = {"lib_angleh2": {"amplitude_dps": 0.03, "phase_deg": 30.0}}


def station_run_folder(workdir: Path, speed: float) -> Path:
    """One full station run of the default procedure on the simulated bench: a population
    part with a bias at twice the table angle (a generic term the bench carries)."""
    from station.sim_run import run_simulated

    part = {"socket": 1, "serial": "SIM-6201", "effects": HIDDEN_ANGLE_2ND}
    t0 = time.perf_counter()
    result, _ = run_simulated([part], procedure_path=DEFAULT_PROCEDURE, out=workdir / "runs",
                              speed=speed)
    print(f"station run ({DEFAULT_PROCEDURE.name}, bench speed {speed:g}): "
          f"{result.station_time_s:.0f} s of station time in {time.perf_counter() - t0:.0f} s "
          f"wall, {result.verdicts[1]}")
    return result.folders[1]


def run_folder_timing(folder: Path, simulate: bool, speed: float) -> None:
    """The workflow's time on a run folder (from first_order); with `simulate`, also the
    time of --simulate (two twin station runs on the bench and the comparison)."""
    from procedures.model.run_folder import load_data

    traj = load_data(folder)
    t0, c0 = time.perf_counter(), time.process_time()
    res = run_discrepancy(traj, first_order_model())
    print(f"workflow time, run folder {folder.name} ({traj.n} samples, "
          f"{traj.time_s[-1] - traj.time_s[0]:.0f} s of station time, {res.blocks.count} "
          f"blocks): {time.perf_counter() - t0:.2f} s wall, "
          f"{time.process_time() - c0:.2f} s CPU, named {res.effects_added}, gap "
          f"{res.gap_final_dps / res.noise_floor_dps:.2f} x floor at the end", flush=True)
    if not simulate:
        return
    from station.discrepancy_simulate import simulate as run_twins

    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        cmp, _ = run_twins(folder, traj, res, Path(out), speed=speed)
        f = cmp.noise_floor_dps
        print(f"--simulate (two twin station runs at bench speed {speed:g} and the "
              f"comparison): {time.perf_counter() - t0:.0f} s; simulation gap "
              f"{cmp.gap_before_dps:.4g} deg/s before ({cmp.gap_before_dps / f:.2f} x floor), "
              f"{cmp.gap_after_dps:.4g} deg/s after ({cmp.gap_after_dps / f:.2f} x), "
              f"{len(cmp.keys)} of {cmp.windows_measured} windows compared")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--effects", default=",".join(MAGNITUDE_PARAM))
    ap.add_argument("--timing-only", action="store_true")
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--run-folder", type=Path, help="also time the workflow on a run folder")
    ap.add_argument("--library-kinds", default="",
                    help=f"comma-separated, or 'all': {','.join(BEYOND_CATALOG)}")
    ap.add_argument("--null-trials", type=int, default=0)
    ap.add_argument("--null-profile", choices=sorted(NULL_PROFILES), default="RAMPED")
    ap.add_argument("--station-run", action="store_true",
                    help="make a full run folder on the simulated bench (default procedure, "
                    "a population part with a bias at twice the table angle) and time the "
                    "workflow on it")
    ap.add_argument("--simulate", action="store_true",
                    help="with --run-folder or --station-run: also time --simulate (two twin "
                    "station runs and the comparison) and print both simulation gaps")
    ap.add_argument("--sim-speed", type=float, default=100.0, help="bench speed factor")
    args = ap.parse_args()
    if not args.skip_timing:
        timing(Profile())
    if args.station_run:
        with tempfile.TemporaryDirectory() as tmp:
            folder = station_run_folder(Path(tmp), args.sim_speed)
            run_folder_timing(folder, args.simulate, args.sim_speed)
    elif args.run_folder:
        run_folder_timing(args.run_folder, args.simulate, args.sim_speed)
    if args.timing_only:
        return
    if args.null_trials:
        null_rate(args.null_trials, args.null_profile)
    if args.library_kinds:
        kinds = list(BEYOND_CATALOG) if args.library_kinds == "all" else \
            args.library_kinds.split(",")
        library_table(kinds, args.trials)
        if not args.effects:
            return
    print(f"\ndetection at alpha=0.01 (Holm), {args.trials} trials per magnitude, SHORT profile")
    print(f"{'effect':20s} {'param':28s} {'realistic':>10s} {'95% named':>10s} "
          f"{'5 sigma':>10s} {'ratio':>6s}")
    for effect in [e for e in args.effects.split(",") if e]:
        m95, log = smallest_detected(effect, args.trials, SHORT)
        m5 = five_sigma_magnitude(effect, 1, SHORT)
        print(f"{effect:20s} {MAGNITUDE_PARAM[effect]:28s} {nominal(effect):10.3g} "
              f"{m95:10.3g} {m5:10.3g} {m95 / m5:6.2f}   [{' '.join(log)}]", flush=True)


if __name__ == "__main__":
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # small dense solves: see discrepancy.py
        main()
