"""One axis of a three-axis run folder as a Trajectory, for the discrepancy workflow per axis.

A three-axis part in its cube sees the table's rate r along the face that points up. Axis j's
output in a window is, in the convention of docs/three-axis.md,

    raw_j = P_jj D_jj w_j + sum_{k != j} P_jk D_kk w_k + b_j(T, V) + G_j . a,   w = r e_up

The run's own fit (record.json `calibration_three_axis`) gives P = M^-1 and G. Taking them as
known, axis j is a single-axis gyro: its output less the cross-axis terms and the
g-sensitivity (with the accelerometer's own reading per sample), against the reference rate
r e_up[j]. Its scale, bias and their temperature and supply terms, and anything the model
lacks, are then the single-axis workflow's to find. The cross-axis terms use D_kk = 1 (a
scale change of 0.5 % times a misalignment of a few mrad is far below the noise).

Only the windows the fit used (static and +/-r plateaus, raw.h5 /segments) are read; the cube
turns between them have no reference.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from procedures.model.run_folder import _read, _windowed_trajectory, raw_sizes
from procedures.model.trajectory import Trajectory
from procedures.runtime.rawdata import RawDataError, read_raw
from procedures.runtime.record import RAW_DATA_FILE, read_record, three_axis_block

AXES = ("x", "y", "z")


def is_three_axis(folder: Path) -> bool:
    """Whether a run folder is a three-axis part's: its record has the three-axis block, or
    (a run that ended before its fit) its raw data hold per-axis samples; the latter is then
    refused by load_axis with one line instead of read as a single-axis part."""
    try:
        if three_axis_block(read_record(folder)) is not None:
            return True
        return raw_sizes(folder / RAW_DATA_FILE)[2]
    except (OSError, ValueError, KeyError):
        return False


def _up(face: str) -> np.ndarray:
    e = np.zeros(3)
    e["xyz".index(face[1])] = 1.0 if face[0] == "+" else -1.0
    return e


def load_axis(folder: Path, axis: str, dut: str | None = None) -> Trajectory:
    """Axis `axis` (x, y or z) of a three-axis run folder as a single-axis trajectory."""
    j = AXES.index(axis)
    record = read_record(folder)
    cal = three_axis_block(record)
    windows = {  # start, end, table rate, face of each window the fit used
        round(w.start_s, 6): (w.start_s, w.end_s, w.table_rate_dps, w.face)
        for w in record.analysis.three_axis_windows or []
        if w.start_s is not None and w.end_s is not None and w.table_rate_dps is not None
    }
    if cal is None or not windows:
        raise ValueError(
            f"{folder}: a three-axis run without its fit (verdict {record.verdict.value}; "
            "record.json has no calibration_three_axis or analysis.three_axis_windows): each "
            "axis is analysed with the run's fit; give a run that reached it"
        )
    rec = _read(folder, dut)
    try:
        raw = read_raw(folder / RAW_DATA_FILE)
        xyz = raw["samples_xyz"]
    except (RawDataError, KeyError) as exc:
        raise ValueError(f"{folder}: raw.h5 has no per-axis samples (/samples_xyz): {exc}") from exc
    rate, accel = _sorted_xyz(folder, raw["samples"], xyz, rec.t_fix.size)
    p = np.linalg.inv(np.asarray(cal.matrix.value, dtype=float))
    g_row = np.asarray(cal.g_sensitivity_dps_per_mps2.value, dtype=float)[j]
    gyro = rate[:, j] - accel @ g_row
    segs = {k: np.array(v, copy=True) for k, v in rec.segs.items()}
    used = []  # (start, end, rate in the part frame) of the windows read
    for k in range(segs["start_s"].size):
        w = windows.get(round(float(segs["start_s"][k]), 6))
        if w is None:
            continue
        start_s, end_s, table_rate_dps, face = w
        w_part = table_rate_dps * _up(face)
        segs["ref_rate_dps"][k] = w_part[j]
        inside = (rec.t_fix >= start_s) & (rec.t_fix <= end_s)
        gyro[inside] -= sum(p[j, c] * w_part[c] for c in range(3) if c != j)
        used.append((start_s, end_s, w_part))
    traj = _windowed_trajectory(dataclasses.replace(rec, gyro=gyro, segs=segs))
    note = (f"axis {axis} of a three-axis part: cross-axis terms and g-sensitivity of the "
            "run's own fit removed")
    variables = _other_axes(traj.time_s, j, used, rec.t_fix, accel)
    return dataclasses.replace(traj, notes=(note, *traj.notes), axis=axis,
                               axis_variables=variables)


def _other_axes(
    time_s: np.ndarray, j: int, used: list[tuple[float, float, np.ndarray]],
    t_fix: np.ndarray, accel: np.ndarray,
) -> dict[str, np.ndarray]:
    """Axis j's trajectory's variables of the part's other axes per sample: the reference
    rate along each other axis (0 outside the windows read) and the accelerometer's reading
    along every axis (its own included: the g-squared term carries the whole linear row)."""
    at = np.searchsorted(t_fix, time_s)
    out: dict[str, np.ndarray] = {}
    for c, name in enumerate(AXES):
        out[f"accel_{name}"] = np.asarray(accel[at, c], dtype=float)
        if c == j:
            continue  # the trajectory's own reference rate
        rate = np.zeros(time_s.size)
        for start_s, end_s, w_part in used:
            rate[(time_s >= start_s) & (time_s <= end_s)] = w_part[c]
        out[f"rate_{name}"] = rate
    return out


def _sorted_xyz(
    folder: Path, s: dict[str, np.ndarray], xyz: dict[str, np.ndarray], n_expected: int
) -> tuple[np.ndarray, np.ndarray]:
    """/samples_xyz in the order `_read` gives /samples (sorted by fixture time, duplicates
    dropped): (n, 3) rates and (n, 3) accelerometer readings."""
    order = np.argsort(s["time_s"], kind="stable")
    t_sorted = s["time_s"][order]
    idx = order[np.concatenate([[True], np.diff(t_sorted) > 0])]
    if idx.size != n_expected:
        raise ValueError(f"{folder}: raw.h5 /samples_xyz does not line up with /samples")
    rate = np.column_stack([xyz[f"rate_{a}_dps"][idx] for a in AXES])
    accel = np.column_stack([xyz[f"accel_{a}_mps2"][idx] for a in AXES])
    return rate, accel
