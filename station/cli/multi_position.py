"""`station analyze multi-position CSV --sections JSON --rate-hz F`: the hand-turned method.

A three-axis session recorded with the part turned by hand (six static faces, one rotation of
a known angle about each axis; docs/multi-position.md). CSV columns `gyr_x, gyr_y, gyr_z`
(deg/s) and, when the part has an accelerometer, `acc_x, acc_y, acc_z` (m/s^2); a `time_s`
column, if there is one, only checks `--rate-hz`; other columns are ignored. The sections
file is a JSON object naming each section's sample indices:
{"x_p": {"start": 0, "end": 800}, ...}, 0-based data rows (the header is not a row), end
exclusive. JSON keys are pinned (docs/interfaces.md); without acc columns G is not estimated
and its two keys are null.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.bounded import MAX_RATE_DPS
from common.csv_rows import shown
from procedures.analysis.errors import AnalysisError
from procedures.analysis.multi_position import (
    AXES,
    SECTIONS,
    MultiPositionResult,
    analyze_multi_position,
)
from station.csv_input import read_csv_rows
from station.errors import UserError

GYRO_COLUMNS = ("gyr_x", "gyr_y", "gyr_z")
ACCEL_COLUMNS = ("acc_x", "acc_y", "acc_z")
MAX_ACCEL_MPS2 = 10_000.0  # about 1000 g: beyond any part's range
MAX_RATE_HZ = 100_000.0
MAX_ROTATION_DEG = 3600.0
RATE_TOLERANCE = 0.01  # a time_s column's median step against 1 / --rate-hz
MAX_INDEX = 10**10
MAX_SECTIONS_BYTES = 100_000
KNOWN_NAMES = frozenset((*SECTIONS, "start", "end"))


class _Span(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    start: int = Field(ge=0, le=MAX_INDEX)
    end: int = Field(ge=1, le=MAX_INDEX)


class SectionsFile(BaseModel):
    """The sections JSON: each of the nine sections by name, nothing else."""

    model_config = ConfigDict(extra="forbid")
    x_p: _Span
    x_a: _Span
    y_p: _Span
    y_a: _Span
    z_p: _Span
    z_a: _Span
    x_rot: _Span
    y_rot: _Span
    z_rot: _Span

    def spans(self) -> dict[str, tuple[int, int]]:
        return {name: (getattr(self, name).start, getattr(self, name).end) for name in SECTIONS}


def add_multi_position(sub: Any) -> None:
    mp = sub.add_parser(
        "multi-position",
        help="three-axis bias, matrix and g-sensitivity from a hand-turned session (Ferraris)",
    )
    mp.add_argument(
        "csv", type=Path, metavar="CSV", help="columns gyr_x, gyr_y, gyr_z [, acc_x, acc_y, acc_z]"
    )
    mp.add_argument(
        "--sections", type=Path, required=True, metavar="JSON",
        help='sample indices of each section: {"x_p": {"start": 0, "end": 800}, ...} '
        f"for {', '.join(SECTIONS)} (end exclusive)",
    )
    mp.add_argument("--rate-hz", type=float, required=True, metavar="F", help="sample rate")
    mp.add_argument(
        "--rotation-deg", type=float, default=360.0, metavar="DEG",
        help="angle of each rotation, right-hand rule about the axis pointing up (default 360; "
        "negative for clockwise seen from above)",
    )
    mp.add_argument(
        "--rotation-uncertainty-deg", type=float, default=0.0, metavar="DEG",
        help="standard (k=1) uncertainty of each rotation's angle: how well the hand stops "
        "where it started (default 0)",
    )
    mp.add_argument("--json", action="store_true", help="print JSON instead of a table")
    mp.set_defaults(handler=run_multi_position)


def check_args(args: argparse.Namespace) -> None:
    """The numbers on the command line, finite and within reason, before any file is read."""
    if not 0 < args.rate_hz <= MAX_RATE_HZ:  # NaN fails too
        raise UserError(f"--rate-hz must be in (0, {MAX_RATE_HZ:g}] Hz, got {args.rate_hz:g}")
    angle = args.rotation_deg
    if not (math.isfinite(angle) and 0 < abs(angle) <= MAX_ROTATION_DEG):
        raise UserError(
            f"--rotation-deg must be non-zero and within +/-{MAX_ROTATION_DEG:g} deg, "
            f"got {angle:g}"
        )
    u = args.rotation_uncertainty_deg
    if not 0 <= u < abs(angle):
        raise UserError(
            f"--rotation-uncertainty-deg must be from 0 to below |--rotation-deg|, got {u:g}"
        )


def read_sections(path: Path) -> dict[str, tuple[int, int]]:
    """The sections JSON as (start, end) per name; UserError naming what to fix."""
    try:
        if path.is_file() and path.stat().st_size > MAX_SECTIONS_BYTES:
            raise UserError(
                f"{path}: {path.stat().st_size} bytes; a sections file is a few hundred: "
                "is this the right file?"
            )
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder; give the sections JSON file") from None
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise UserError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from None
    try:
        return SectionsFile.model_validate(doc).spans()
    except ValidationError as exc:
        raise UserError(f"{path}: " + "; ".join(_problems(exc))) from None


def _problems(exc: ValidationError, most: int = 4) -> list[str]:
    """One phrase per problem (missing sections together), the user's names quoted safely."""
    missing, out = [], []
    for err in exc.errors():
        loc = [repr(p)[:40] if isinstance(p, str) and p not in KNOWN_NAMES else str(p)
               for p in err["loc"]]
        if err["type"] == "missing" and len(loc) == 1:
            missing.append(loc[0])
        elif err["type"] == "extra_forbidden" and len(loc) == 1:
            out.append(f"unknown section {loc[0]} (the names are {', '.join(SECTIONS)})")
        elif err["type"] == "model_type" and not loc:
            out.append('the file must hold one object: {"x_p": {"start": 0, "end": 800}, ...}')
        else:
            out.append(f"{'.'.join(loc)}: {err['msg']}")
    if missing:
        out.insert(0, f"section(s) {', '.join(missing)} missing (all of {', '.join(SECTIONS)} "
                   "are needed)")
    if len(out) > most:
        out = [*out[:most], f"and {len(out) - most} more problem(s)"]
    if any(":" in o and not o.startswith(("section", "unknown", "the file")) for o in out):
        out.append('each section is {"start": N, "end": N}, end exclusive')
    return out


def read_session_csv(
    path: Path,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """gyr (n, 3) in deg/s; acc (n, 3) in m/s^2 when all three columns are there; time_s
    when there is such a column (only to check --rate-hz)."""
    rows = read_csv_rows(path, ",".join(GYRO_COLUMNS))
    header = [h.strip() for h in rows[0]]
    missing = [c for c in GYRO_COLUMNS if c not in header]
    if missing:
        raise UserError(
            f"{path}: missing column(s) {', '.join(missing)} (found {_some(header)}); "
            f"the header row must name {', '.join(GYRO_COLUMNS)}"
        )
    acc_found = [c for c in ACCEL_COLUMNS if c in header]
    if acc_found and len(acc_found) < 3:
        absent = [c for c in ACCEL_COLUMNS if c not in header]
        raise UserError(
            f"{path}: has {', '.join(acc_found)} but not {', '.join(absent)}; give all three "
            "accelerometer columns or none"
        )
    gyro = _columns(path, rows, header, GYRO_COLUMNS, MAX_RATE_DPS)
    accel = _columns(path, rows, header, ACCEL_COLUMNS, MAX_ACCEL_MPS2) if acc_found else None
    time_s = _columns(path, rows, header, ("time_s",), 1e9)[:, 0] if "time_s" in header else None
    return gyro, accel, time_s


def check_rate(path: Path, time_s: NDArray[np.float64] | None, rate_hz: float) -> None:
    """With a time_s column, its median step must agree with --rate-hz (integrals use it)."""
    if time_s is None or time_s.size < 3:
        return
    step_s = float(np.median(np.diff(time_s)))
    if not abs(step_s * rate_hz - 1.0) <= RATE_TOLERANCE:
        seen = f"{1.0 / step_s:.6g} Hz" if step_s > 0 else "not increasing"
        raise UserError(
            f"{path}: time_s steps by {step_s:.6g} s ({seen}) but --rate-hz is {rate_hz:g}; "
            "give the rate the record was sampled at"
        )


def _some(names: list[str], most: int = 12) -> str:
    shown = ", ".join(n[:40] for n in names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def _columns(
    path: Path, rows: list[list[str]], header: list[str], names: tuple[str, ...], bound: float
) -> NDArray[np.float64]:
    index = [header.index(c) for c in names]
    out = np.empty((len(rows) - 1, len(names)))
    for r, row in enumerate(rows[1:]):
        for k, (i, name) in enumerate(zip(index, names, strict=True)):
            text = row[i].strip() if i < len(row) else ""
            try:
                value = float(text)
            except ValueError:
                raise UserError(
                    f"{path}: line {r + 2}, column {name}: {shown(text)} is not a number"
                ) from None
            if not math.isfinite(value):
                raise UserError(
                    f"{path}: line {r + 2}, column {name}: {shown(text)}; NaN or infinite values "
                    "cannot be analysed: repair or remove that row"
                )
            if abs(value) > bound:
                raise UserError(
                    f"{path}: line {r + 2}, column {name}: {value:g} is beyond +/-{bound:g}; "
                    "check the units (deg/s and m/s^2)"
                )
            out[r, k] = value
    return out


def run_multi_position(args: argparse.Namespace) -> int:
    check_args(args)
    sections = read_sections(args.sections)
    gyro, accel, time_s = read_session_csv(args.csv)
    check_rate(args.csv, time_s, args.rate_hz)
    try:
        result = analyze_multi_position(
            gyro,
            sections,
            args.rate_hz,
            rotation_deg=args.rotation_deg,
            u_rotation_deg=args.rotation_uncertainty_deg,
            accel_mps2=accel,
        )
    except AnalysisError as exc:
        raise UserError(f"{args.csv} with {args.sections}: {exc}") from None
    warnings = list(result.warnings)
    if accel is None:
        warnings.append(
            "no acc_x, acc_y, acc_z columns: the g-sensitivity G is not estimated (null); "
            "each rotation's offset is taken from the face it was made in"
        )
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(result_json(result, warnings), indent=2))
    else:
        print(result_table(result))
    return 0


def _listed(a: NDArray[np.float64] | None) -> Any:
    return None if a is None else a.tolist()


def result_json(r: MultiPositionResult, warnings: list[str]) -> dict[str, Any]:
    return {
        "gyro_bias_dps": _listed(r.bias_dps),
        "gyro_bias_dps_uncertainty_k2": _listed(r.u_bias_dps_k2),
        "gyro_matrix": _listed(r.matrix),
        "gyro_matrix_uncertainty_k2": _listed(r.u_matrix_k2),
        "gyro_g_sensitivity_dps_per_mps2": _listed(r.g_sensitivity_dps_per_mps2),
        "gyro_g_sensitivity_dps_per_mps2_uncertainty_k2": _listed(
            r.u_g_sensitivity_dps_per_mps2_k2
        ),
        "g_sensitivity_estimated": r.g_sensitivity_dps_per_mps2 is not None,
        "correction": "w_hat = M (raw - b - G a)",
        "uncertainty_coverage": "k=2",
        "rotation_deg": r.rotation_deg,
        "sample_rate_hz": r.sample_rate_hz,
        "rotation_integrals_deg": _listed(r.rotation_integrals_deg),
        "face_pairs_chi2": r.pairs_chi2,
        "face_pairs_dof": r.pairs_dof,
        "bias_birge_ratio": r.bias_birge_ratio,
        "warnings": warnings,
    }


def result_table(r: MultiPositionResult) -> str:
    head = "".join(f"{a:>12}{'':11}" for a in AXES)
    lines = [
        "three-axis gyro, hand-turned (Ferraris) method; correction w_hat = M (raw - b - G a)",
        f"rotations of {r.rotation_deg:+g} deg at {r.sample_rate_hz:g} Hz; "
        "uncertainties are k=2",
        "",
        f"{'bias b (deg/s)':<14}{head}",
        " " * 14 + _row(r.bias_dps, r.u_bias_dps_k2),
        "",
        f"{'matrix M':<14}{head}",
        *(f"{'  ' + a:<14}" + _row(r.matrix[i], r.u_matrix_k2[i]) for i, a in enumerate(AXES)),
        "",
    ]
    g, u_g = r.g_sensitivity_dps_per_mps2, r.u_g_sensitivity_dps_per_mps2_k2
    if g is None or u_g is None:
        lines.append("g-sensitivity G: not estimated (the CSV has no acc_x, acc_y, acc_z)")
    else:
        lines += [
            f"{'G (deg/s per m/s^2)':<14}",
            f"{'':<14}{head}",
            *(f"{'  ' + a:<14}" + _row(g[i], u_g[i]) for i, a in enumerate(AXES)),
        ]
    lines += [
        "",
        "each rotation as measured (offsets removed), deg on x, y, z:",
        *(
            f"  {name}  " + "  ".join(f"{v:+10.3f}" for v in r.rotation_integrals_deg[:, j])
            for j, name in enumerate(("x_rot", "y_rot", "z_rot"))
        ),
    ]
    if r.warnings:
        lines += ["", *(f"!!! WARNING: {w}" for w in r.warnings)]
    return "\n".join(lines)


def _row(values: NDArray[np.float64], u_k2: NDArray[np.float64]) -> str:
    return "".join(f"{v:>+12.6f} +/-{u:<7.2g}" for v, u in zip(values, u_k2, strict=True))
