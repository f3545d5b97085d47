"""`station analyze stop-method|allan|multi-position CSV`: calibration analysis of a recorded CSV.

CSV columns `time_s, rate_dps` (header row required; extra columns ignored, an optional
`status` column carries the fixture's status bits). JSON keys are pinned in docs/interfaces.md; keys
beyond them are additions.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.bounded import MAX_RATE_DPS
from common.csv_rows import shown
from drivers.fixture_protocol import RATED_RANGE_DPS
from procedures.analysis.allan import AllanAnalysis, analyze_allan, check_static
from procedures.analysis.errors import AnalysisError
from procedures.analysis.stop_method import (
    StopMethodResult,
    StopMethodSettings,
    analyze_stop_method,
)
from station.cli.multi_position import add_multi_position
from station.csv_input import read_csv_rows
from station.errors import UserError

REQUIRED = ("time_s", "rate_dps")
# plausible values of each column: a record is at most years long, a rate within any
# table's reach, status a 32-bit word of flags
COLUMN_BOUNDS = {
    "time_s": (-1e9, 1e9),
    "rate_dps": (-MAX_RATE_DPS, MAX_RATE_DPS),
    "status": (0.0, float(2**32 - 1)),
}
MIN_ROWS = 16


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("analyze", help="analyse a recorded rate CSV (stop method, Allan)")
    sub = p.add_subparsers(dest="analysis", metavar="ANALYSIS")
    p.set_defaults(handler=lambda _args: _help(p))

    sm = sub.add_parser(
        "stop-method",
        help="bias and scale correction from a record of moves between two mechanical stops",
    )
    sm.add_argument("csv", type=Path, metavar="CSV", help="columns time_s, rate_dps [, status]")
    sm.add_argument(
        "--reference-angle", type=float, default=90.0, metavar="DEG",
        help="angle between the stops, measured independently (default 90)",
    )
    sm.add_argument(
        "--reference-angle-uncertainty", type=float, default=0.0, metavar="DEG",
        help="standard (k=1) uncertainty of the reference angle (default 0)",
    )
    sm.add_argument(
        "--full-scale", type=float, default=None, metavar="DPS",
        help="treat |rate| beyond this as over-range even without status bits "
        f"(default: the part's rated range, {RATED_RANGE_DPS:g})",
    )
    sm.add_argument("--json", action="store_true", help="print JSON instead of a table")
    sm.set_defaults(handler=run_stop_method)

    al = sub.add_parser("allan", help="Allan deviation and noise terms of a static record")
    al.add_argument("csv", type=Path, metavar="CSV", help="columns time_s, rate_dps")
    al.add_argument("--json", action="store_true", help="print JSON instead of a table")
    al.set_defaults(handler=run_allan)

    add_multi_position(sub)


def _help(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def read_rate_csv(path: Path) -> dict[str, NDArray[np.float64]]:
    """Columns of a rate CSV as float arrays; UserError naming the problem otherwise."""
    rows = read_csv_rows(path, "time_s,rate_dps")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise UserError(
            f"{path}: missing column(s) {', '.join(missing)} (found {shown(','.join(header))}); "
            "the header row must name time_s and rate_dps"
        )
    wanted = [c for c in (*REQUIRED, "status") if c in header]
    cols: dict[str, list[float]] = {c: [] for c in wanted}
    for line_no, row in enumerate(rows[1:], start=2):
        for c in wanted:
            i = header.index(c)
            text = row[i].strip() if i < len(row) else ""
            try:
                cols[c].append(float(text))
            except ValueError:
                raise UserError(
                    f"{path}: line {line_no}, column {c}: {shown(text)} is not a number"
                ) from None
    data = {c: np.asarray(v, dtype=np.float64) for c, v in cols.items()}
    n = data["time_s"].size
    if n < MIN_ROWS:
        raise UserError(
            f"{path}: {n} data rows; the record is too short (need at least {MIN_ROWS})"
        )
    for c, arr in data.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            raise UserError(
                f"{path}: column {c} holds NaN or infinite values (first at data row "
                f"{int(np.argmax(bad)) + 1}); repair or remove those rows"
            )
        low, high = COLUMN_BOUNDS[c]
        bad = (arr < low) | (arr > high)
        if c == "status":
            bad |= arr != np.round(arr)
        if bad.any():
            i = int(np.argmax(bad))
            raise UserError(
                f"{path}: column {c} holds {float(arr[i]):.6g} at data row {i + 1}, outside "
                f"{low:g}..{high:g}" + (" or not a whole number" if c == "status" else "")
                + "; this is not a plausible record"
            )
    steps = np.diff(data["time_s"])
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        raise UserError(
            f"{path}: time_s is not increasing at data row {i + 2} "
            f"({float(data['time_s'][i]):.10g} then {float(data['time_s'][i + 1]):.10g}); "
            "sort the record"
        )
    return data


def check_stop_method_args(args: argparse.Namespace) -> None:
    """The numbers on the command line, finite and within reason, before the file is read."""
    angle = args.reference_angle
    if not 0 < angle <= 360:  # NaN fails too
        raise UserError(f"--reference-angle must be in (0, 360] deg, got {angle:g}")
    u = args.reference_angle_uncertainty
    if not 0 <= u < angle:
        raise UserError(
            f"--reference-angle-uncertainty must be from 0 to below the angle, got {u:g}"
        )
    fs = args.full_scale
    if fs is not None and not 0 < fs <= MAX_RATE_DPS:
        raise UserError(f"--full-scale must be in (0, {MAX_RATE_DPS:g}] deg/s, got {fs:g}")


def run_stop_method(args: argparse.Namespace) -> int:
    check_stop_method_args(args)
    data = read_rate_csv(args.csv)
    full_scale = RATED_RANGE_DPS if args.full_scale is None else args.full_scale
    # a hand-cut record may begin in the tail of a move: used from its end, with a warning,
    # as the station's own stop step does (procedures/steps/stop.py)
    settings = StopMethodSettings(full_scale_dps=full_scale, trim_leading_motion=True)
    hint = (
        f"the over-range check uses the part's rated range +/-{RATED_RANGE_DPS:g} deg/s by "
        "default; for a part with a wider range pass --full-scale DPS"
        if args.full_scale is None
        else f"the over-range check uses --full-scale {full_scale:g} deg/s"
    )
    try:
        result = analyze_stop_method(
            data["time_s"],
            data["rate_dps"],
            reference_angle_deg=args.reference_angle,
            u_reference_angle_deg=args.reference_angle_uncertainty,
            status=data["status"].astype(np.int64) if "status" in data else None,
            settings=settings,
        )
        if result.n_over_range:
            result = dataclasses.replace(result, warnings=(*result.warnings, hint))
        result.require_scale_correction()
    except AnalysisError as exc:
        raise UserError(f"{args.csv}: {exc}") from None
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(stop_method_json(result), indent=2))
    else:
        print(stop_method_table(result))
    return 0


def stop_method_json(r: StopMethodResult) -> dict[str, Any]:
    return {
        "bias_dps": r.bias_dps,
        "bias_correction_dps": r.bias_correction_dps,
        "moves": [
            {
                "start_s": m.start_s,
                "end_s": m.end_s,
                "measured_angle_deg": m.measured_angle_deg,
                "scale_correction": m.scale_correction,
                "u_scale_correction": m.u_scale_correction,
                "u_measured_angle_deg": m.u_measured_angle_deg,
                "peak_rate_dps": m.peak_rate_dps,
                "n_over_range": m.n_over_range,
            }
            for m in r.moves
        ],
        "scale_correction": r.scale_correction,
        "u_scale_correction": r.u_scale_correction,
        "scale": r.scale,
        "u_scale": r.u_scale,
        "u_bias_dps": r.bias.u_bias_dps,
        "bias_window_s": r.bias.duration_s,
        "reference_angle_deg": r.reference_angle_deg,
        "u_reference_angle_deg": r.u_reference_angle_deg,
        "n_over_range": r.n_over_range,
        "over_range_intervals_s": [list(span) for span in r.over_range_intervals_s],
        "moves_consistent": r.moves_consistent,
        "moves_chi2": r.moves_chi2,
        "moves_dof": r.moves_dof,
        "birge_ratio": r.birge_ratio,
        "uncertainty_coverage": "k=1 (standard)",
        "u_scale_correction_k2": r.u_scale_correction_k2,
        "u_bias_dps_k2": r.bias.u_bias_dps_k2,
        "warnings": list(r.warnings),
    }


def stop_method_table(r: StopMethodResult) -> str:
    lines = [
        f"bias                {r.bias_dps:+10.4f} deg/s   u(k=2) {r.bias.u_bias_dps_k2:.2g} deg/s"
        f"   from the first {r.bias.duration_s:.3g} s",
        f"bias correction     {r.bias_correction_dps:+10.4f} deg/s",
        "",
        f"{'move':>4}  {'start_s':>8}  {'end_s':>8}  {'angle_deg':>10}  {'scale_corr':>10}  "
        f"{'u(k=2)':>8}  note",
    ]
    for i, m in enumerate(r.moves, start=1):
        corr = "-" if m.scale_correction is None else f"{m.scale_correction:.4f}"
        u = "-" if m.u_scale_correction is None else f"{2 * m.u_scale_correction:.2g}"
        note = "CLIPPED: refused" if m.clipped else ("" if m.complete else "incomplete")
        lines.append(
            f"{i:>4}  {m.start_s:8.3f}  {m.end_s:8.3f}  {m.measured_angle_deg:+10.3f}  "
            f"{corr:>10}  {u:>8}  {note}"
        )
    lines.append("")
    if r.scale_correction is not None and r.u_scale_correction is not None:
        lines.append(
            f"scale correction    {r.scale_correction:.4f}   u(k=2) {2 * r.u_scale_correction:.2g}"
            f"   (scale {r.scale:.4f})"
        )
    if r.moves_consistent is False:
        lines += [
            "",
            f"!!! MOVES DISAGREE: chi-square {r.moves_chi2:.3g} on {r.moves_dof} degree(s) of "
            "freedom;",
            "!!! the per-move corrections are not consistent, the mean is doubtful, and its",
            f"!!! u(k=2) above is widened by the Birge ratio {r.birge_ratio:.3g}",
        ]
    return "\n".join(lines)


def run_allan(args: argparse.Namespace) -> int:
    data = read_rate_csv(args.csv)
    dt = _even_step_s(args.csv, data["time_s"])
    try:
        result = analyze_allan(data["rate_dps"], 1.0 / dt)
    except AnalysisError as exc:
        raise UserError(f"{args.csv}: {exc}") from None
    static = check_static(data["rate_dps"], 1.0 / dt)
    warnings = [] if static.static else [static.message()]
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(allan_json(result, dt, static.static, warnings), indent=2))
    else:
        print(allan_table(result, warnings))
    return 0


def _even_step_s(csv: str, t: NDArray[np.float64]) -> float:
    """The record's sample step (s); UserError naming the first gap when it is uneven."""
    steps = np.diff(t)
    dt = float(np.median(steps))
    irregular = np.abs(steps - dt) > 0.25 * dt
    if irregular.any():
        i = int(np.argmax(irregular))
        n_irr = int(irregular.sum())
        raise UserError(
            f"{csv}: samples are not evenly spaced: a step of {float(steps[i]):.6g} s from "
            f"t = {float(t[i]):.6g} s to t = {float(t[i + 1]):.6g} s (data rows {i + 1}-{i + 2}), "
            f"where the median step is {dt:.6g} s"
            + (f" ({n_irr} irregular steps in all)" if n_irr > 1 else "")
            + "; the Allan deviation needs an unbroken record: re-record or analyse the "
            "section without gaps"
        )
    return dt


def allan_json(
    result: AllanAnalysis, dt: float, record_static: bool, warnings: list[str]
) -> dict[str, Any]:
    noise = result.noise
    bi_resolved = noise.flat_region_s is not None
    rrw_resolved = noise.rrw_region_s is not None
    return {
        "tau_s": result.adev.tau_s.tolist(),
        "adev_dps": result.adev.adev_dps.tolist(),
        "arw_deg_per_sqrt_h": noise.arw_deg_per_sqrt_h,
        # null when the flat part is not seen: read the upper bound instead
        "bias_instability_deg_per_h": noise.bias_instability_deg_per_h if bi_resolved else None,
        "bias_instability_resolved": bi_resolved,
        "u_arw_deg_per_sqrt_h": noise.u_arw_deg_per_sqrt_h,
        "u_bias_instability_deg_per_h": (
            noise.u_bias_instability_deg_per_h if bi_resolved else None
        ),
        "bias_instability_upper_bound_deg_per_h": result.bias_instability_upper_bound_deg_per_h,
        "rrw_deg_per_h_per_sqrt_h": (
            noise.model.rrw_deg_per_h_per_sqrt_h if rrw_resolved else None
        ),
        "rrw_resolved": rrw_resolved,
        "rrw_upper_bound_deg_per_h_per_sqrt_h": result.rrw_upper_bound_deg_per_h_per_sqrt_h,
        "arw_region_s": noise.arw_region_s,
        "flat_region_s": noise.flat_region_s,
        "rrw_region_s": noise.rrw_region_s,
        "sample_rate_hz": 1.0 / dt,
        "n_samples": result.adev.n_samples,
        "uncertainty_coverage": "k=1 (standard)",
        "record_static": record_static,
        "warnings": warnings,
    }


def allan_table(result: AllanAnalysis, warnings: list[str]) -> str:
    noise = result.noise
    lines = [f"{'tau_s':>12}  {'adev_dps':>12}  {'model_dps':>12}"]
    model = noise.model.adev_dps(result.adev.tau_s)
    for tau, ad, md in zip(result.adev.tau_s, result.adev.adev_dps, model, strict=True):
        lines.append(f"{tau:12.5g}  {ad:12.5g}  {md:12.5g}")
    lines += [
        "",
        f"angle random walk   {noise.arw_deg_per_sqrt_h:.4g} deg/sqrt(h)"
        f"   u(k=2) {2 * noise.u_arw_deg_per_sqrt_h:.2g}   {_region(noise.arw_region_s)}",
        (
            f"bias instability    {noise.bias_instability_deg_per_h:.4g} deg/h"
            f"   u(k=2) {2 * noise.u_bias_instability_deg_per_h:.2g}   "
            f"{_region(noise.flat_region_s)}"
            if noise.flat_region_s is not None
            else "bias instability    not resolved in this record: at most "
            f"{result.bias_instability_upper_bound_deg_per_h:.3g} deg/h (lowest ADEV / 0.664)"
        ),
        (
            f"rate random walk    {noise.model.rrw_deg_per_h_per_sqrt_h:.4g} deg/h/sqrt(h)"
            f"   {_region(noise.rrw_region_s)}"
            if noise.rrw_region_s is not None
            else "rate random walk    not resolved in this record: at most "
            f"{result.rrw_upper_bound_deg_per_h_per_sqrt_h:.3g} deg/h/sqrt(h)"
            " (min of ADEV x sqrt(3 / tau))"
        ),
    ]
    if warnings:
        lines += ["", *(f"!!! WARNING: {w}" for w in warnings)]
    return "\n".join(lines)


def _region(region: tuple[float, float] | None) -> str:
    if region is None:
        return "(not seen in this record)"
    lo, hi = region
    return f"(dominant from {lo:.3g} to {hi:.3g} s)"
