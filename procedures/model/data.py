"""Load discrepancy data (a CSV or a run folder) into one typed Trajectory.

CSV (pinned columns): time_s, gyro_dps, ref_rate_dps, ref_angle_deg, temp_c, supply_v;
extra columns are allowed. An optional `segment_kind` column names each row's window
(static, plateau, stop_move, ...); without it the windows are inferred from the reference
rate. `time_s` counts from power-on. Run folders are read by run_folder.py.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from procedures.model.trajectory import FloatArray, Segment, Trajectory

CSV_COLUMNS = ("time_s", "gyro_dps", "ref_rate_dps", "ref_angle_deg", "temp_c", "supply_v")
STILL_RATE_DPS = 0.05
STEADY_ACCEL_DPS2 = 2.0
MIN_STEADY_S = 1.0
STOP_MOVE_MIN_DEG = 5.0


def trajectory_from_columns(
    columns: Mapping[str, Sequence[float] | FloatArray],
    segments: Sequence[Segment] | None = None,
    kinds: Sequence[str] | None = None,
    time_since_power_on_s: FloatArray | None = None,
    source: str = "",
    serial: str = "",
) -> Trajectory:
    """Build a Trajectory from the pinned columns; infer segments if none are given."""
    missing = [c for c in CSV_COLUMNS if c not in columns]
    if missing:
        raise ValueError(
            f"{source or 'data'}: columns {missing} are missing; the discrepancy data needs "
            f"{', '.join(CSV_COLUMNS)}"
        )
    arr = {c: np.asarray(columns[c], dtype=float) for c in CSV_COLUMNS}
    order = np.argsort(arr["time_s"], kind="stable")
    if np.any(order != np.arange(order.size)):
        arr = {c: v[order] for c, v in arr.items()}
        kinds = [kinds[i] for i in order] if kinds is not None else None
    t = arr["time_s"]
    if segments is None:
        segments = segments_from_kinds(t, kinds) if kinds is not None else infer_segments(
            t, arr["ref_rate_dps"], arr["ref_angle_deg"]
        )
    return Trajectory(
        time_s=t,
        gyro_dps=arr["gyro_dps"],
        ref_rate_dps=arr["ref_rate_dps"],
        ref_angle_deg=arr["ref_angle_deg"],
        temp_c=arr["temp_c"],
        supply_v=arr["supply_v"],
        time_since_power_on_s=t if time_since_power_on_s is None else time_since_power_on_s,
        segments=tuple(segments),
        source=source,
        serial=serial,
    )


def segments_from_kinds(time_s: FloatArray, kinds: Sequence[str]) -> list[Segment]:
    """Runs of equal `segment_kind` labels become segments."""
    step = float(np.median(np.diff(time_s)))
    out: list[Segment] = []
    start = 0
    for i in range(1, len(kinds) + 1):
        if i == len(kinds) or kinds[i] != kinds[start]:
            kind = str(kinds[start]).strip() or "transition"
            out.append(Segment(kind, float(time_s[start]), float(time_s[i - 1]) + step))
            start = i
    return out


def infer_segments(
    time_s: FloatArray, rate_dps: FloatArray, angle_deg: FloatArray
) -> list[Segment]:
    """Windows from the reference: steady rate >= 1 s is static or plateau, the rest
    transitions; a transition between two static windows that turns the table by more than
    5 deg is a stop move."""
    step = float(np.median(np.diff(time_s)))
    accel = np.gradient(rate_dps, time_s)
    width = max(int(round(0.2 / step)), 1)
    accel_s = np.convolve(np.abs(accel), np.ones(width) / width, mode="same")
    steady = accel_s < STEADY_ACCEL_DPS2
    labels: list[tuple[str, int, int]] = []
    start = 0
    for i in range(1, steady.size + 1):
        if i == steady.size or steady[i] != steady[start]:
            labels.append(("steady" if steady[start] else "transition", start, i))
            start = i
    segs: list[tuple[str, int, int]] = []
    for kind, a, b in labels:
        if kind == "steady" and (time_s[b - 1] - time_s[a]) >= MIN_STEADY_S:
            still = np.median(np.abs(rate_dps[a:b])) < STILL_RATE_DPS
            segs.append(("static" if still else "plateau", a, b))
        elif segs and segs[-1][0] == "transition":
            segs[-1] = ("transition", segs[-1][1], b)
        else:
            segs.append(("transition", a, b))
    for i in range(1, len(segs) - 1):
        if (
            segs[i][0] == "transition"
            and segs[i - 1][0] == "static"
            and segs[i + 1][0] == "static"
            and abs(angle_deg[segs[i][2] - 1] - angle_deg[segs[i][1]]) > STOP_MOVE_MIN_DEG
        ):
            segs[i] = ("stop_move", segs[i][1], segs[i][2])
    return [Segment(k, float(time_s[a]), float(time_s[b - 1]) + step) for k, a, b in segs]


def load_csv(path: Path) -> Trajectory:
    """Read a discrepancy CSV; ValueError says which column or row is wrong."""
    if not path.exists():
        raise ValueError(f"{path}: file not found")
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None:
            raise ValueError(f"{path}: empty file; expected a header {', '.join(CSV_COLUMNS)}")
        fields = [f.strip() for f in reader.fieldnames]
        missing = [c for c in CSV_COLUMNS if c not in fields]
        if missing:
            raise ValueError(
                f"{path}: columns {missing} are missing; the header must hold "
                f"{', '.join(CSV_COLUMNS)} (extra columns are allowed)"
            )
        values: dict[str, list[float]] = {c: [] for c in CSV_COLUMNS}
        kinds: list[str] | None = [] if "segment_kind" in fields else None
        for lineno, row in enumerate(reader, start=2):
            row = {k.strip(): v for k, v in row.items() if k is not None}
            for c in CSV_COLUMNS:
                try:
                    values[c].append(float(row[c]))
                except (TypeError, ValueError):
                    raise ValueError(
                        f"{path}: line {lineno}: column {c} is {row.get(c)!r}, not a number"
                    ) from None
            if kinds is not None:
                kinds.append(row.get("segment_kind") or "")
    if len(values["time_s"]) < 10:
        raise ValueError(f"{path}: only {len(values['time_s'])} rows; a whole run is needed")
    return trajectory_from_columns(values, kinds=kinds, source=str(path))


def write_csv(path: Path, traj: Trajectory, with_kinds: bool = True) -> Path:
    """Write a Trajectory as a discrepancy CSV (the pinned columns, optional segment_kind)."""
    kinds = np.full(traj.n, "transition", dtype=object)
    for seg in traj.segments:
        a = int(np.searchsorted(traj.time_s, seg.start_s, side="left"))
        b = int(np.searchsorted(traj.time_s, seg.end_s, side="left"))
        kinds[a:b] = seg.kind
    cols = [traj.time_s, traj.gyro_dps, traj.ref_rate_dps, traj.ref_angle_deg, traj.temp_c,
            traj.supply_v]
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow([*CSV_COLUMNS, *(["segment_kind"] if with_kinds else [])])
        for i in range(traj.n):
            row = [f"{c[i]:.9g}" for c in cols]
            if with_kinds:
                row.append(kinds[i])
            w.writerow(row)
    return path
