"""Accuracy against the simulated bench's truth, over many simulated parts.

For each part: every fitted coefficient against the truth of the bench, in units of its own
k = 2 uncertainty (|fit - truth| / U; <= 1 means covered), and the residual scale error after
correction at the verification rates. Prints one row per part and a summary, with the RMS
of each condition's bias and scale error over its own uncertainty (k = 1) and of the
stop-vs-table E_n (1 when the stated uncertainties are the scatter).

    python3 benchmarks/bench_accuracy.py [--parts 24] [--sockets 8] [--speed X]
                                         [--procedure config/procedures/eol-rate-table.yaml]
                                         [--strategy setpoint|fastest]
                                         [--thermal-physics honest|ideal]
                                         [--option overlap_measurement supply_change_no_wait]
                                         [--revisit-c 3] [--keep-declared]

`--thermal-physics` sets the simulated parts' thermal physics (docs/simulated-bench.md;
default: the sim config's); the truth's coefficients are the sensing element's. With `ideal`
the product runs without its `thermal_typical` (its parts have no lag or hysteresis to
correct), unless `--keep-declared`. The
corrected-scale error is, per part, the largest |fitted scale law / true scale law - 1| in
ppm over the part's conditions, both laws at the condition's temperature and supply.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402
from bench_cycle import OPTIONS, with_strategy  # noqa: E402

from procedures.runtime.record import read_record  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402

COEFFS = (
    "bias_dps",
    "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale",
    "scale_temp_coeff_per_c",
    "scale_supply_coeff_per_v",
)
SHORT = {
    "bias_dps": "b0",
    "bias_temp_coeff_dps_per_c": "bT",
    "bias_supply_coeff_dps_per_v": "bV",
    "scale": "s0",
    "scale_temp_coeff_per_c": "sT",
    "scale_supply_coeff_per_v": "sV",
}


def condition_ratios(rec: Any, tr: dict[str, float]) -> dict[str, list[float]]:
    """Per condition: (measured - truth) / u (k = 1) of the bias and the scale the fit took,
    truth at the condition's own die temperature and supply; and the stop-vs-table E_n."""
    out: dict[str, list[float]] = {"bias": [], "scale": [], "en": []}
    cal = rec.calibration
    t0 = cal.reference_temperature_c if cal is not None else 25.0
    v0 = cal.reference_supply_v if cal is not None else 5.0
    fit = rec.analysis.fit
    for c in (fit.model_dump(mode="json")["conditions"] if fit is not None else []):
        dv = c["supply_v"] - v0
        bias = (
            tr["bias_dps"]
            + tr["bias_temp_coeff_dps_per_c"] * (c["bias_temp_c"] - t0)
            + tr["bias_supply_coeff_dps_per_v"] * dv
        )
        scale = tr["scale"] * (
            1.0
            + tr["scale_temp_coeff_per_c"] * (c["scale_temp_c"] - t0)
            + tr["scale_supply_coeff_per_v"] * dv
        )
        # the bias as fitted (hysteresis-corrected) with its correction's u, when it has one
        u_bias = math.hypot(c["u_bias_dps"], c.get("u_hysteresis_correction_dps", 0.0))
        out["bias"].append((c["bias_dps"] - bias) / u_bias)
        out["scale"].append((c["scale"] - scale) / c["u_scale"])
    out["en"] = [
        m.value
        for m in rec.measurements
        if m.name == "stop_table_consistency" and m.value is not None
    ]
    return out


def scale_law(c: dict[str, float], dt: float, dv: float) -> float:
    """scale (1 + sT dT + sV dV) with coefficients `c` (truth or fit)."""
    return c["scale"] * (
        1.0 + c["scale_temp_coeff_per_c"] * dt + c["scale_supply_coeff_per_v"] * dv
    )


def corrected_scale_ppm(rec: Any, tr: dict[str, float]) -> float | None:
    """Largest |fitted scale law / true scale law - 1| over the part's conditions, ppm."""
    cal, fit = rec.calibration, rec.analysis.fit
    if cal is None or fit is None:
        return None
    fitted = {k: getattr(cal, k).value for k in COEFFS}
    worst = 0.0
    for c in fit.model_dump(mode="json")["conditions"]:
        dt = c["scale_temp_c"] - cal.reference_temperature_c
        dv = c["supply_v"] - cal.reference_supply_v
        err = scale_law(fitted, dt, dv) / scale_law(tr, dt, dv) - 1.0
        worst = max(worst, abs(err) * 1e6)
    return worst


def with_declaration(proc_path: Path, out: Path, revisit_c: float | None = None,
                     undeclared: bool = False) -> Path:
    """The procedure, or a copy with conditions.revisit_c set (its product path made
    absolute); `undeclared`: its product a copy without thermal_typical (for parts without
    the honest physics: the declaration describes the parts)."""
    if revisit_c is None and not undeclared:
        return proc_path
    data = yaml.safe_load(proc_path.read_text())
    if revisit_c is not None:
        data["conditions"]["revisit_c"] = revisit_c
    if "product" in data:
        data["product"] = str((proc_path.parent / data["product"]).resolve())
        if undeclared:
            product = yaml.safe_load(Path(data["product"]).read_text())
            product.pop("thermal_typical", None)
            copy_product = out / f"{Path(data['product']).stem}-undeclared.yaml"
            copy_product.write_text(yaml.safe_dump(product, sort_keys=False))
            data["product"] = str(copy_product)
    copy = out / f"{proc_path.stem}-declared-{revisit_c}-{undeclared}.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False))
    return copy


def print_condition_ratios(per_part: list[dict[str, list[float]]]) -> None:
    """RMS of each ratio over every part and condition: 1 when the stated uncertainty is
    the scatter (below 1: intervals too wide; above: too narrow)."""
    for key, what in (
        ("bias", "per-condition bias error / u"),
        ("scale", "per-condition scale error / u"),
        ("en", "stop-vs-table E_n"),
    ):
        v = [x for p in per_part for x in p[key]]
        if v:
            rms = math.sqrt(sum(x * x for x in v) / len(v))
            beyond = sum(abs(x) > 3 for x in v)
            print(f"{what}: rms {rms:.2f} over {len(v)} (1 = as stated), |.| > 3: {beyond}")


def part_row(rec: Any, tr: dict[str, float]) -> dict[str, Any]:
    """One part's figures against its truth `tr` (the truth's `parameters`)."""
    row: dict[str, Any] = {
        "serial": rec.dut.serial, "verdict": str(rec.verdict), "z": {}, "res": None
    }
    if rec.calibration is not None:
        for k in COEFFS:
            c = getattr(rec.calibration, k)
            row["z"][k] = abs(c.value - tr[k]) / c.uncertainty_k2
        row["b0"] = (rec.calibration.bias_dps.value - tr["bias_dps"],
                     rec.calibration.bias_dps.uncertainty_k2)
    if rec.verification:
        row["res"] = rec.verification.max_error_pct
    row["cond"] = condition_ratios(rec, tr)
    row["ppm"] = corrected_scale_ppm(rec, tr)
    row["again"] = len(rec.analysis.measured_again)
    return row


def print_rows(rows: list[dict[str, Any]]) -> str:
    """The per-part table; returns its header (for the rule under the table)."""
    head = (
        f"{'serial':<10} {'verdict':<7} " + " ".join(f"{SHORT[k]:>6}" for k in COEFFS)
        + "  resid%  scale ppm"
    )
    print(
        "\n|fit - truth| / U(k=2) per coefficient (<= 1: covered), "
        "residual scale error after correction"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        zs = " ".join(f"{r['z'][k]:6.2f}" if k in r["z"] else f"{'-':>6}" for k in COEFFS)
        res = f"{r['res']:.4f}" if r["res"] is not None else "-"
        ppm = f"{r['ppm']:9.1f}" if r["ppm"] is not None else f"{'-':>9}"
        print(f"{r['serial']:<10} {r['verdict']:<7} {zs}  {res:>6}  {ppm}")
    return head


def print_coverage(fitted: list[dict[str, Any]]) -> None:
    total = covered = 0
    for k in COEFFS:
        zs = [r["z"][k] for r in fitted]
        c = sum(z <= 1.0 for z in zs)
        total += len(zs)
        covered += c
        print(f"coverage {SHORT[k]}: {c}/{len(zs)} = {100 * c / max(len(zs), 1):.0f} %")
    print(
        f"coverage all coefficients: {covered}/{total} = {100 * covered / max(total, 1):.1f} % "
        f"(target 93 to 97 %: k = 2 intervals neither too narrow nor too wide)"
    )


def print_b0(fitted: list[dict[str, Any]]) -> None:
    """The b0 error's mean (a hysteresis left in b0 shows as a mean near h/2) and U."""
    errs = [r["b0"][0] for r in fitted]
    us = sorted(r["b0"][1] for r in fitted)
    if errs:
        print(f"b0 error: mean {sum(errs) / len(errs):+.4f} deg/s, median U (k=2) "
              f"{us[len(us) // 2]:.4f} deg/s")


def print_scale(rows: list[dict[str, Any]]) -> None:
    res = [r["res"] for r in rows if r["res"] is not None]
    if res:
        print(
            f"residual scale error after correction: max {max(res):.4f} %, "
            f"{sum(x < 0.05 for x in res)}/{len(res)} below 0.05 %"
        )
    ppms = sorted(r["ppm"] for r in rows if r["ppm"] is not None)
    if ppms:
        print(
            f"corrected scale vs the element's truth: max {ppms[-1]:.1f} ppm, median "
            f"{ppms[len(ppms) // 2]:.1f} ppm, {sum(x <= 100 for x in ppms)}/{len(ppms)} "
            "within 100 ppm"
        )


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=24)
    ap.add_argument("--sockets", type=int, default=8)
    ap.add_argument("--speed", type=float, default=None, help="scaled clock (default: lockstep)")
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-rate-table.yaml"))
    ap.add_argument("--first-serial", type=int, default=5001)
    ap.add_argument("--strategy", choices=["setpoint", "fastest"], default=None,
                    help="override the procedure's chamber.strategy (in a copy)")
    ap.add_argument("--option", nargs="*", choices=OPTIONS, default=[],
                    help="the thermal step's faster options to turn on (in a copy)")
    ap.add_argument("--revisit-c", type=float, default=None,
                    help="set the procedure's conditions.revisit_c (in a copy): one more "
                    "condition reached from the other side of the hysteresis")
    ap.add_argument("--keep-declared", action="store_true",
                    help="with --thermal-physics ideal, keep the product's thermal_typical "
                    "(default: left out, as the parts have none of it)")
    ap.add_argument("--thermal-physics", choices=["honest", "ideal"], default=None,
                    help="the simulated parts' thermal physics (default: the sim config's)")
    return ap.parse_args()


def main() -> int:
    args = parse_args()
    sim_config = (
        {"part_physics": {"thermal": {"mode": args.thermal_physics}}}
        if args.thermal_physics
        else None
    )
    rows: list[dict[str, Any]] = []
    out = Path(tempfile.mkdtemp(prefix="bench-accuracy-"))
    serial = args.first_serial
    procedure = Path(args.procedure)
    if args.strategy is not None or args.option:
        procedure = with_strategy(procedure, args.strategy, out, args.option)
    undeclared = args.thermal_physics == "ideal" and not args.keep_declared
    procedure = with_declaration(procedure, out, args.revisit_c, undeclared)
    if undeclared:
        print("parts without the honest physics: the product's thermal_typical left out")
    t0 = time.monotonic()
    while len(rows) < args.parts:
        n = min(args.sockets, args.parts - len(rows))
        parts = [{"socket": s, "serial": f"SIM-{serial + s - 1:04d}"} for s in range(1, n + 1)]
        serial += n
        result, truth = run_simulated(
            parts, procedure_path=procedure, out=out, speed=args.speed, sim_config=sim_config
        )
        for s in sorted(result.folders):
            rows.append(part_row(read_record(result.folders[s]),
                                 truth["sockets"][str(s)]["parameters"]))
        print(f"  ... {len(rows)} parts done ({time.monotonic() - t0:.0f} s wall)", flush=True)
    head = print_rows(rows)
    fitted = [r for r in rows if r["z"]]
    print("-" * len(head))
    print_coverage(fitted)
    print_b0(fitted)
    print_scale(rows)
    print_condition_ratios([r["cond"] for r in rows])
    print(
        f"parts {len(rows)}, fitted {len(fitted)}, verdicts "
        + ", ".join(
            f"{v}: {sum(r['verdict'] == v for r in rows)}"
            for v in sorted({r["verdict"] for r in rows})
        )
    )
    again = sum(r["again"] for r in rows)
    print(f"conditions measured again (overlap_measurement): {again}")
    print(f"wall time {time.monotonic() - t0:.0f} s; run folders in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
