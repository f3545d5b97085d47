"""Cycle time per load: station time, thermal wait, measurement time, a physics lower bound.

Per load (one UUT cycle of 1, 4 or 8 sockets) with the chamber strategy `setpoint` and/or
`fastest` (the procedure's chamber.strategy is overridden in a copy):
  station     = the run's station time (record timings.total),
  thermal     = the thermal steps' waits (condition set to measurement start, summed),
  measurement = station - thermal,
  bound       = physics bound on the thermal waits + the measurement floor, where
                thermal bound = per condition, the soonest any setpoint profile within the
                chamber's limits (ramp rate, setpoint limits, the part's maximum) makes the die
                meet the step's stability criterion, for the die lag the run learned (the
                product's value with `setpoint`) and the self-heating the parts showed
                (procedures.thermal.chamber_profile.settle_bound_s: a linear programme), and
                measurement floor = per condition, the bias averaging time for the target
                accuracy (from the measured angle random walk) + the plateau and stop-method
                dwells, + the verification dwells,
  ratio       = station / bound (bound*, ratio*: the die also within band / 2 of its
                final reading from the window's end on, not merely creeping within the
                criterion's slope limit; load, ratio: every part's die at once under the one
                chamber they share, each with its own self-heating: no one setpoint profile
                answers dies that heat differently as well as each alone).
The bench runs in lockstep (station time is physics time) unless --speed asks for a scaled
clock.

    python3 benchmarks/bench_cycle.py [--sockets 1 4 8] [--strategy setpoint fastest]
                                      [--thermal-physics honest|ideal]
                                      [--option overlap_measurement supply_change_no_wait]

--option turns the `thermal` step's faster options on in the copy (docs/procedures.md,
"Faster procedure options"); `again` counts the conditions measured again over the load.
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from procedures.analysis.allan import NoiseModel  # noqa: E402
from procedures.analysis.bias import required_averaging_time_s  # noqa: E402
from procedures.loading.config import load_procedure, load_product  # noqa: E402
from procedures.runtime.record import RunRecord, read_record  # noqa: E402
from procedures.thermal.chamber_profile import load_settle_bound_s, settle_bound_s  # noqa: E402
from procedures.thermal.chamber_strategy import (  # noqa: E402
    Criterion,
    DieState,
    ThermalLimits,
    ThermalModel,
)
from procedures.thermal.ramp_turn import RampModel, ramp_bound_s  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402


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


OPTIONS = ("overlap_measurement", "supply_change_no_wait")


def _set_thermal_options(steps: list[dict[str, object]], options: list[str]) -> None:
    """Every `thermal` entry, also inside loops, with the options on."""
    for entry in steps:
        if entry.get("step") == "thermal":
            entry.update({option: True for option in options})
        inner = entry.get("steps")
        if isinstance(inner, list):
            _set_thermal_options(inner, options)


def with_strategy(
    proc_path: Path, strategy: str | None, out: Path, options: list[str] | None = None
) -> Path:
    """A copy of the procedure with chamber.strategy set (None: the procedure's) and the
    thermal step's `options` on (its product path made absolute)."""
    data = yaml.safe_load(proc_path.read_text())
    if strategy is not None:
        data.setdefault("chamber", {})["strategy"] = strategy
    _set_thermal_options(data.get("steps", []), options or [])
    if data.get("product"):
        data["product"] = str((proc_path.parent / data["product"]).resolve())
    copy = out / f"{proc_path.stem}-{strategy}.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    return copy


def thermal_wait_s(record: RunRecord) -> float:
    stab = record.analysis.stability.values()
    return sum((v.measurement_start_station_s or 0.0) - (v.condition_set_station_s or 0.0)
               for v in stab)


def thermal_bound_s(
    proc_path: Path, records: list[RunRecord], ambient_c: float = 25.0, near_final: bool = False,
    load: bool = False,
) -> float:
    """Sum over the conditions of the physics bound for the slowest part (see the module);
    with `load`, for every part at once under the one chamber they share."""
    proc, _ = load_procedure(proc_path)
    product, _ = load_product((proc_path.parent / str(proc.product)).resolve())
    thermal = proc.settings_of("thermal")
    # the lag learned where the die was driven (the temperature change), the slowest part's
    taus = [
        v.die_tau_s
        for r in records
        for v in r.analysis.stability.values()
        if v.die_tau_s and v.overshoot_c
    ]
    tau_s = max(taus, default=product.die_tau_s)
    model = ThermalModel(
        air_tau_s=proc.chamber.air_tau_s,
        die_tau_s=tau_s,
        ramp_c_per_min=proc.chamber.ramp_c_per_min,
    )
    high_c = product.max_part_temperature_c or 125.0
    limits = ThermalLimits(setpoint_high_c=high_c, max_part_c=high_c)
    total = 0.0
    air_c, heat = ambient_c, {r.dut.socket: 0.0 for r in records}  # powered just before
    conditions = list(records[0].analysis.stability.items())
    for name, _ in conditions:
        target = _temp_of(name)
        new_heat = {}
        for r in records:
            stab = r.analysis.stability[name]
            new_heat[r.dut.socket] = (stab.die_temperature_c or target) - target
        dies = {
            s: DieState(
                die_c=air_c + heat[s], tau_s=tau_s, heat_c=heat[s], heat_final_c=new_heat[s],
                heat_tau_s=product.self_heating_tau_s,
            )
            for s in new_heat
        }
        crit = Criterion(
            thermal.window_s, thermal.slope_c_per_min, thermal.band_c, target,
            thermal.target_tolerance_c,
        )
        if load:
            worst = load_settle_bound_s(
                model, limits, air_c, list(dies.values()), target, crit, near_final=near_final
            )
        else:  # the part with the largest self-heating step governs
            sock = max(new_heat, key=lambda s: abs(new_heat[s] - heat[s]))
            worst = settle_bound_s(
                model, limits, air_c, dies[sock], target, crit, near_final=near_final
            )
        total += worst if math.isfinite(worst) else 0.0
        air_c, heat = target, new_heat
    return total


def ramp_thermal_bound_s(proc_path: Path) -> float:
    """A ramp procedure's thermal bound: the soonest the die covers its span both ways on this
    chamber (procedures.thermal.ramp_turn.ramp_bound_s), with the product's die lag and the
    step's setpoint limits (default: the product's part temperature limits)."""
    proc, _ = load_procedure(proc_path)
    product, _ = load_product((proc_path.parent / str(proc.product)).resolve())
    ramp = proc.settings_of("ramp_calibration")
    temps = proc.conditions.temperatures_c
    model = RampModel(proc.chamber.ramp_c_per_min, proc.chamber.air_tau_s, product.die_tau_s)
    low = ramp.min_setpoint_c if ramp.min_setpoint_c is not None else (
        product.min_part_temperature_c if product.min_part_temperature_c is not None else -40.0)
    high = ramp.max_setpoint_c if ramp.max_setpoint_c is not None else (
        product.max_part_temperature_c or 125.0)
    return ramp_bound_s(model, min(temps), max(temps), (low, high))


def _temp_of(condition: str) -> float:
    """T45_V5.25 -> 45.0"""
    return float(condition.split("_")[0].lstrip("T"))


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sockets", type=int, nargs="+", default=[1, 4, 8])
    ap.add_argument(
        "--strategy", nargs="+", choices=["setpoint", "fastest"], default=["setpoint", "fastest"]
    )
    ap.add_argument("--speed", type=float, default=None, help="scaled clock (default: lockstep)")
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-rate-table.yaml"))
    ap.add_argument("--thermal-physics", choices=["honest", "ideal"], default=None,
                    help="the simulated parts' thermal physics (default: the sim config's)")
    ap.add_argument("--option", nargs="*", choices=OPTIONS, default=[],
                    help="the thermal step's faster options to turn on")
    return ap.parse_args()


def measure_load(
    args: argparse.Namespace, strategy: str, proc_path: Path, n: int, out: Path
) -> tuple[Any, ...]:
    """One lockstep load of `n` sockets: its row of the table."""
    sim_extra = (
        {"part_physics": {"thermal": {"mode": args.thermal_physics}}}
        if args.thermal_physics else None
    )
    parts = [{"socket": s, "serial": f"SIM-{7000 + 10 * n + s:04d}"} for s in range(1, n + 1)]
    w0, c0 = time.monotonic(), cpu_s()
    result, _ = run_simulated(
        parts, procedure_path=proc_path, out=out, speed=args.speed, sim_config=sim_extra
    )
    wall, cpu = time.monotonic() - w0, cpu_s() - c0
    recs = [read_record(result.folders[s]) for s in sorted(result.folders)]
    total = max(r.timings.get("total", 0.0) for r in recs)
    thermal = thermal_wait_s(recs[0])
    arws = [r.analysis.allan.arw_deg_per_sqrt_h if r.analysis.allan else None for r in recs]
    arw = max(a for a in arws if a) if any(arws) else 0.6
    floor = measurement_floor_s(proc_path, arw)
    if load_procedure(proc_path)[0].settings_of("ramp_calibration") is not None:
        bound = settled = shared = ramp_thermal_bound_s(proc_path) + floor
    else:
        bound = thermal_bound_s(proc_path, recs) + floor
        settled = thermal_bound_s(proc_path, recs, near_final=True) + floor
        shared = thermal_bound_s(proc_path, recs, load=True) + floor
    again = sum(len(r.analysis.measured_again) for r in recs)
    verdicts = f"{again:5d}  " + ",".join(str(r.verdict) for r in recs)
    print(f"  ... {strategy}, {n} socket(s) done in {wall:.0f} s wall", flush=True)
    return (strategy, n, total, thermal, bound, settled, shared, floor, wall, cpu, verdicts)


def print_table(rows: list[tuple[Any, ...]]) -> None:
    head = (
        f"{'strategy':>8} {'sockets':>7} {'station':>8} {'thermal':>8} {'measure':>8} "
        f"{'bound':>7} {'(therm':>7} {'+ meas)':>7} {'ratio':>6} {'bound*':>7} {'ratio*':>6} "
        f"{'load':>6} {'ratio':>6} {'per part':>8} {'parts/h':>7} {'bound/h':>7} "
        f"{'wall s':>7} {'cpu s':>6} {'again':>5}  verdicts"
    )
    print(head)
    print("-" * len(head))
    for strategy, n, total, thermal, bound, settled, shared, floor, wall, cpu, verdicts in rows:
        print(
            f"{strategy:>8} {n:7d} {total / 60:8.1f} {thermal / 60:8.1f} "
            f"{(total - thermal) / 60:8.1f} {bound / 60:7.1f} {(bound - floor) / 60:7.1f} "
            f"{floor / 60:7.1f} {total / bound:6.2f} {settled / 60:7.1f} {total / settled:6.2f} "
            f"{shared / 60:6.1f} {total / shared:6.2f} "
            f"{total / n / 60:8.2f} {3600 * n / total:7.1f} {3600 * n / shared:7.1f} "
            f"{wall:7.1f} {cpu:6.0f} {verdicts}"
        )
    print("parts/h: sockets per station hour of the load; bound/h: the same at the load bound")
    print("bound: the stability criterion met for good (the reading may creep at up to the")
    print("slope limit); bound*: also within band/2 of its final value from then on;")
    print("load: the bound for every part at once under the one chamber they share (the part")
    print("with the largest self-heating step alone governs `bound`); a ramp procedure's")
    print("bound: the die over its span up and back down at the chamber's fastest (its rest")
    print("after the ramp not included) + the verification dwells")
    print("cpu s: the station's and the bench's CPU time (in lockstep the two take turns, so on")
    print("an idle machine the wall time is about the cpu time; on a loaded one it is longer)")


def main() -> int:
    args = parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench-cycle-"))
    rows = []
    for strategy in args.strategy:
        proc_path = with_strategy(Path(args.procedure), strategy, out, args.option)
        rows += [measure_load(args, strategy, proc_path, n, out) for n in args.sockets]
    pace = "in lockstep" if args.speed is None else f"at {args.speed:g}x"
    opts = ", ".join(args.option) or "none"
    print(f"\nprocedure {Path(args.procedure).name}, bench {pace}, thermal options: {opts}; "
          "times in station minutes")
    print_table(rows)
    print(f"run folders in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
