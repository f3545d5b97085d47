"""`station discrepancy RUN --simulate` over several parts: the simulation gaps against their
floor, and which windows carry the gap (prints figures; not a timed test).

For each serial: a station run of the shortened procedure (tests/model/data/eol-simulate.yaml)
on the simulated bench with a population part and a hidden bias at twice the table angle,
then `station discrepancy RUN --model first_order --simulate`; printed: the effects named, the
simulation gap before/after against its floor, and the window pieces (windows cut to at most
10 s) that carry most of the "after" gap with the die temperature, table rate and table angle
of the measured and the twin piece (so a gap from the part's model can be told from one of
the run's inputs).

    python3 benchmarks/bench_discrepancy_simulate.py [--serials SIM-6101,SIM-6102,...]
        [--amplitude 0.04] [--sim-speed X] [--keep DIR]

Without --sim-speed the bench runs in lockstep (station time is physics time), for the
measured run and the twins alike.

With --thermal (issue 29): the honest thermal bench instead of a hidden harmonic. The parts
(population parts with the bench's default honest thermal physics: element lag, gradient
bias, hysteresis, socket air; tests/model/thermal_station.py) run a procedure together, one
socket each, in lockstep; then `station discrepancy FOLDER --model first_order --simulate`
on each part's folder (the twins on a bench with the thermal physics off, carrying the found
terms). Printed per folder: the effects named, the simulation gap before/after against its
floor, the pieces compared (and how many are ramp plateaus), and the largest die temperature
difference measured - twin over the compared ramp plateau pieces.

    python3 benchmarks/bench_discrepancy_simulate.py --thermal [--procedure PATH]
        [--serials SIM-2931,SIM-2932,...] [--bench honest|ideal|gradient-only|...] [--alone]
        [--keep DIR]

With --alone each part runs in a station run of its own; without, the parts run together
and each twin runs among the others (`--simulate`'s companions: a ramp turns when the last
die of the load has covered the span). The difference between the two (and the die offset
of a twin on another bench's air, given back as the socket's air) is in docs/discrepancy.md.
The last figure per folder is `definition_gap`: the extended twin's run against the model as
the station evaluates it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "model"))

PROCEDURE = ROOT / "tests" / "model" / "data" / "eol-simulate.yaml"


def _window_inputs(folder: Path, serial: str
                   ) -> dict[tuple[str, str, int, int], tuple[float, ...]]:
    """(die temperature, table rate, table angle, supply, centre time) per compared piece."""
    from procedures.model.blocks import block_mean
    from procedures.model.run_folder import load_data
    from procedures.model.twin import windows_of

    traj = load_data(folder, dut=serial)
    w = windows_of(traj)
    temp = block_mean(traj.temp_c, w.start, w.stop)
    supply = block_mean(traj.supply_v, w.start, w.stop)
    return {k: (float(temp[i]), float(w.rate_dps[i]), float(w.angle_deg[i]),
                float(supply[i]), float(w.center_s[i]))
            for i, k in enumerate(w.keys)}


def one_part(serial: str, amplitude: float, speed: float | None, work: Path) -> dict[str, float]:
    from station.cli import main as cli
    from station.sim_run import run_simulated

    part = {"socket": 1, "serial": serial,
            "effects": {"lib_angleh2": {"amplitude_dps": amplitude, "phase_deg": 30.0}}}
    t0 = time.perf_counter()
    result, _ = run_simulated([part], procedure_path=PROCEDURE, out=work / "measured",
                              speed=speed)
    folder = result.folders[1]
    t_run = time.perf_counter() - t0
    out = work / "disc"
    args = ["discrepancy", str(folder), "--model", "first_order", "--simulate", "--out",
            str(out)]
    if speed is not None:
        args += ["--sim-speed", f"{speed:g}"]
    t0 = time.perf_counter()
    code = cli.main(args)
    t_disc = time.perf_counter() - t0
    res = json.loads((out / "discrepancy.json").read_text())
    floor = res["simulation_noise_floor_dps"]
    before, after = res["simulation_gap_before_dps"], res["simulation_gap_after_dps"]
    print(f"{serial}: exit {code}, measured run {result.verdicts[1]} in {t_run:.0f} s, "
          f"discrepancy --simulate {t_disc:.0f} s; named {res['effects_added']}; "
          f"gap {res['gap_final_dps'] / res['noise_floor_dps']:.2f} x floor; simulation gap "
          f"before {before / floor:.2f} x, after {after / floor:.2f} x floor "
          f"({floor:.4g} deg/s), {res['simulation_windows_compared']} of "
          f"{res['simulation_windows_measured']} window pieces", flush=True)
    meas_in = _window_inputs(folder, serial)
    twin_in = _window_inputs(Path(res["simulation_twin_after"]["run_folder"]), serial)
    wins = res["simulation_windows"]
    total = sum(w["duration_s"] * w["residual_after_dps"] ** 2 for w in wins)
    wins.sort(key=lambda w: -w["duration_s"] * w["residual_after_dps"] ** 2)
    for w in wins[:6]:
        key = (w["condition"], w["kind"], w["ordinal"], w["piece"])
        m, t = meas_in.get(key), twin_in.get(key)
        share = w["duration_s"] * w["residual_after_dps"] ** 2 / total
        print(f"    {w['condition']:>12s} {w['kind']:11s} #{w['ordinal']:<2d}.{w['piece']:<3d} "
              f"{w['duration_s']:6.1f} s  after {w['residual_after_dps']:+.5f} "
              f"({100 * share:4.1f} %)  before {w['residual_before_dps']:+.5f}", end="")
        if m and t:
            print(f"  dT meas-twin {m[0] - t[0]:+.3f} C, rate {m[1] - t[1]:+.4f} dps, "
                  f"angle {m[2]:.1f}/{t[2]:.1f}, t {m[4]:.0f}/{t[4]:.0f} s")
        else:
            print()
    return {"before": before / floor, "after": after / floor}


def thermal_folders(serials: list[str], procedure: Path, work: Path, bench: str
                    ) -> dict[str, Path]:
    """One lockstep run of `procedure` on `bench` (thermal_station.BENCHES) with these
    parts, one socket each: each part's run folder (PASS or FAIL)."""
    from thermal_station import BENCHES

    from station.sim_run import run_simulated

    parts = [{"socket": i + 1, "serial": s} for i, s in enumerate(serials)]
    t0 = time.perf_counter()
    result, _ = run_simulated(parts, procedure_path=procedure, out=work / "measured",
                              speed=None,
                              sim_config={"part_physics": {"thermal": BENCHES[bench]}})
    print(f"{procedure.name}: {len(serials)} parts in {time.perf_counter() - t0:.0f} s: "
          + ", ".join(f"{s} {result.verdicts[i + 1]}" for i, s in enumerate(serials)),
          flush=True)
    return {s: result.folders[i + 1] for i, s in enumerate(serials)
            if str(result.verdicts[i + 1]) in ("PASS", "FAIL")}


def definition_gap(out: Path, serial: str, floor: float) -> float:
    """The extended model's twin run against the extended model as the station evaluates it
    on that run (its own dT/dt, 10 s centred average of the die sensor across gaps up to
    30 s; its own play operator), piece by piece, as the duration-weighted RMS of the piece
    means' difference over the floor: what differs between the bench's generic terms and
    the station's library terms (the twin is quiet, so noise is 1 % of the measured)."""
    from procedures.model.model_io import load_model
    from procedures.model.run_folder import load_data
    from procedures.model.twin import weighted_rms, windows_of

    res = json.loads((out / "discrepancy.json").read_text())
    traj = load_data(Path(res["simulation_twin_after"]["run_folder"]), dut=serial)
    model = load_model(out / "model.yaml")
    w = windows_of(traj)
    predicted = model.predict(traj)
    from procedures.model.blocks import block_mean

    diff = w.mean_dps - block_mean(predicted, w.start, w.stop)
    diff = diff - np.average(diff, weights=w.duration_s)  # the bias: the run's own fit
    return weighted_rms(diff, w.duration_s) / floor


def thermal_one(serial: str, folder: Path, out: Path) -> dict[str, float]:
    """`--simulate` on one part's folder of the honest bench: its row."""
    from station.cli import main as cli

    t0 = time.perf_counter()
    code = cli.main(["discrepancy", str(folder), "--model", "first_order", "--simulate",
                     "--out", str(out)])
    res = json.loads((out / "discrepancy.json").read_text())
    floor = res["simulation_noise_floor_dps"]
    before, after = res["simulation_gap_before_dps"], res["simulation_gap_after_dps"]
    wins = res["simulation_windows"]
    ramp = [w for w in wins if w["kind"] == "ramp_plateau"]
    d_temp = [abs(w["die_temp_c"] - w["twin_die_temp_c"]) for w in ramp]
    print(f"{serial} {folder.name}: exit {code} in {time.perf_counter() - t0:.0f} s; named "
          f"{res['effects_added'] or '-'}; simulation gap before {before:.4f} "
          f"({before / floor:.2f} x), after {after:.4f} ({after / floor:.2f} x), floor "
          f"{floor:.4f} deg/s; {res['simulation_windows_compared']} of "
          f"{res['simulation_windows_measured']} pieces compared, {len(ramp)} ramp plateau "
          f"pieces (die temperature meas - twin at most "
          f"{max(d_temp, default=math.nan):.3f} C); the extended twin against its model as "
          f"the station evaluates it {definition_gap(out, serial, floor):.2f} x floor; notes "
          f"{res['simulation_notes']}", flush=True)
    return {"before": before / floor, "after": after / floor}


def thermal(serials: list[str], procedure: Path, work: Path, bench: str, alone: bool
            ) -> list[dict[str, float]]:
    folders: dict[str, Path] = {}
    if alone:  # each part its own station run: the twin's schedule is the measured one's
        for serial in serials:
            folders |= thermal_folders([serial], procedure, work / serial, bench)
    else:
        folders = thermal_folders(serials, procedure, work, bench)
    out = []
    for serial, folder in folders.items():
        try:
            out.append(thermal_one(serial, folder, work / f"disc_{serial}"))
        except (OSError, RuntimeError, ValueError, KeyError) as exc:
            print(f"{serial}: left out ({type(exc).__name__}: {exc})", flush=True)
    return out


def _patient_bench_start(timeout_s: float) -> None:
    """A bench on a machine loaded by other work can take more than the launcher's 20 s to
    write its state file; this benchmark waits longer rather than lose the part."""
    import functools

    from drivers.sim import launcher

    launcher.launch_bench = functools.partial(
        launcher.launch_bench, start_timeout_s=timeout_s)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--serials", default="SIM-6101,SIM-6102,SIM-6103,SIM-6104")
    ap.add_argument("--amplitude", type=float, default=0.04)
    ap.add_argument("--sim-speed", type=float, default=None)
    ap.add_argument("--keep", type=Path, help="keep the run folders under this folder")
    ap.add_argument("--bench-start-timeout", type=float, default=120.0)
    ap.add_argument("--thermal", action="store_true",
                    help="the honest thermal bench's parts, no hidden harmonic")
    ap.add_argument("--procedure", type=Path, default=ROOT / "config" / "procedures"
                    / "eol-ramp.yaml", help="with --thermal: the procedure the parts run")
    ap.add_argument("--alone", action="store_true",
                    help="with --thermal: each part in a station run of its own")
    ap.add_argument("--bench", default="honest",
                    help="with --thermal: honest, ideal, gradient-only or hysteresis-only")
    args = ap.parse_args()
    _patient_bench_start(args.bench_start_timeout)
    ratios = []
    if args.thermal:
        serials = args.serials.split(",")
        if args.keep:
            ratios = thermal(serials, args.procedure, args.keep, args.bench, args.alone)
        else:
            with tempfile.TemporaryDirectory() as tmp:
                ratios = thermal(serials, args.procedure, Path(tmp), args.bench, args.alone)
        args.serials = ""
    for serial in filter(None, args.serials.split(",")):
        try:
            if args.keep:
                work = args.keep / serial
                work.mkdir(parents=True, exist_ok=True)
                ratios.append(one_part(serial, args.amplitude, args.sim_speed, work))
            else:
                with tempfile.TemporaryDirectory() as tmp:
                    ratios.append(one_part(serial, args.amplitude, args.sim_speed, Path(tmp)))
        except (OSError, RuntimeError, ValueError, KeyError) as exc:  # e.g. a bench that
            # could not start on a loaded machine: that part is left out, the others count
            print(f"{serial}: left out ({type(exc).__name__}: {exc})", flush=True)
    if not ratios:
        return
    after = np.array([r["after"] for r in ratios])
    before = np.array([r["before"] for r in ratios])
    mode = "lockstep" if args.sim_speed is None else f"speed {args.sim_speed:g}"
    print(f"{len(ratios)} parts ({mode}): simulation gap after / floor: max {after.max():.2f}, "
          f"median {np.median(after):.2f}; before / floor: min {before.min():.2f}, median "
          f"{np.median(before):.2f}")


if __name__ == "__main__":
    main()
