"""Load a run folder (record.json + raw.h5) into a Trajectory for the discrepancy workflow.

The engine logs the table only at encoder snapshots (start and end of each plateau, at the
stops), so the reference between analysed windows is unknown. Only samples inside windows
with a known reference are used: static, stabilise, stop_static, position_static (rate 0;
the last from the optional multi-position step, loaded as static) and plateau (the
window's reference rate; angle advancing from the nearest snapshot). Stop moves are used
only where the table log is dense enough to follow the motion (< 0.1 s between rows).
Verify windows are left out: the part runs with its new compensation there.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from procedures.model.data import load_csv
from procedures.model.trajectory import FloatArray, Segment, Trajectory
from procedures.rawdata import RawDataError, read_raw
from procedures.record import RAW_DATA_FILE, RECORD_FILE, read_record

log = logging.getLogger(__name__)

STATIC_KINDS = ("static", "stabilise", "stop_static", "position_static")
DENSE_TABLE_S = 0.1


def find_run_folder(path: Path, dut: str | None) -> Path:
    """The run folder itself, or the newest run folder of `dut` under a results folder."""
    if (path / RECORD_FILE).exists():
        return path
    candidates = sorted(p.parent for p in path.glob(f"*/{RECORD_FILE}"))
    if dut:
        candidates = [c for c in candidates if _serial(c) == dut]
    if not candidates:
        raise ValueError(
            f"{path}: no run folder here (no {RECORD_FILE})"
            + (f" for part {dut}" if dut else "")
            + "; give a run folder or a CSV"
        )
    if len(candidates) > 1 and not dut:
        raise ValueError(
            f"{path}: holds {len(candidates)} run folders; pick one with --dut SERIAL "
            "or give the run folder itself"
        )
    return candidates[-1]


def _serial(folder: Path) -> str | None:
    try:
        return read_record(folder).dut.serial
    except ValueError:
        return None


def load_data(path: Path, dut: str | None = None) -> Trajectory:
    """A CSV file or a run folder (or a folder of run folders, with `dut`)."""
    if path.is_file():
        if path.suffix.lower() != ".csv":
            raise ValueError(f"{path}: expected a .csv file or a run folder")
        return load_csv(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file or folder")
    return load_run_folder(find_run_folder(path, dut), dut)


def _static_angle(
    tab_t: FloatArray, tab_pos: FloatArray, tab_rate: FloatArray, start_s: float, end_s: float
) -> float:
    """Where the table rests during a static window: the engine snapshots the encoder at the
    end of a static wait, so the first row from the window's start (up to 2 s past its end)
    is at the window's angle; failing that, the last row before it if the table was at rest."""
    if tab_t.size == 0:
        return 0.0
    i = int(np.searchsorted(tab_t, start_s, side="left"))
    if i < tab_t.size and tab_t[i] <= end_s + 2.0:
        return float(tab_pos[i])
    if i > 0 and abs(tab_rate[i - 1]) < 0.01:
        return float(tab_pos[i - 1])
    return float(np.interp(start_s, tab_t, tab_pos))


def _plateau_angle(
    table_t: FloatArray, table_pos: FloatArray, t_station: FloatArray, rate: float
) -> FloatArray:
    if table_t.size == 0:
        return np.zeros_like(t_station)
    i = int(np.argmin(np.abs(table_t - t_station[0])))
    return table_pos[i] + rate * (t_station - table_t[i])


def load_run_folder(folder: Path, dut: str | None = None) -> Trajectory:
    record = read_record(folder)
    if dut and record.dut.serial != dut:
        raise ValueError(
            f"{folder}: this run is of part {record.dut.serial}, not {dut}; check --dut"
        )
    try:
        raw = read_raw(folder / RAW_DATA_FILE)
    except RawDataError as exc:
        raise ValueError(str(exc)) from exc
    s = raw["samples"]
    if s["time_s"].size < 100:
        raise ValueError(f"{folder}: the raw data holds only {s['time_s'].size} samples")
    order = np.argsort(s["time_s"], kind="stable")
    t_fix = s["time_s"][order]
    keep_unique = np.concatenate([[True], np.diff(t_fix) > 0])
    idx = order[keep_unique]
    t_fix = s["time_s"][idx]
    t_sta = s["station_time_s"][idx]
    gyro = s["rate_dps"][idx]
    temp = s["temp_c"][idx]
    tab = raw["table"]
    tab_order = np.argsort(tab["station_time_s"])
    tab_t = tab["station_time_s"][tab_order]
    tab_pos = tab["position_deg"][tab_order]
    tab_rate = tab["rate_dps"][tab_order]
    sup = raw["supply"]
    sup_t, sup_v = sup["station_time_s"], sup["voltage_v"]
    power_on_s = float(sup_t.min()) if sup_t.size else float(t_sta[0])
    notes = []
    if not sup_t.size:
        notes.append("no supply log: time since power-on counted from the first sample")

    segs = raw["segments"]
    use = np.zeros(t_fix.size, dtype=bool)
    ref_rate = np.zeros(t_fix.size)
    ref_angle = np.zeros(t_fix.size)
    supply = np.full(t_fix.size, np.nan)
    segments: list[Segment] = []
    skipped_moves = 0
    for k in np.argsort(segs["start_s"]):
        kind = str(segs["kind"][k])
        a = int(np.searchsorted(t_fix, segs["start_s"][k], side="left"))
        b = int(np.searchsorted(t_fix, segs["end_s"][k], side="right"))
        if b - a < 3 or kind == "verify":
            continue
        if np.any(use[a:b]):  # overlapping windows: the first one keeps its samples
            a = a + int(np.argmin(use[a:b])) if not np.all(use[a:b]) else b
            if b - a < 3:
                continue
        ts = t_sta[a:b]
        seg_v = float(segs["supply_v"][k])
        if kind in STATIC_KINDS:
            ref_rate[a:b] = 0.0
            ref_angle[a:b] = _static_angle(tab_t, tab_pos, tab_rate, float(ts[0]), float(ts[-1]))
        elif kind == "plateau":
            rate = float(segs["ref_rate_dps"][k])
            if not np.isfinite(rate):
                continue
            ref_rate[a:b] = rate
            ref_angle[a:b] = _plateau_angle(tab_t, tab_pos, ts, rate)
        elif kind == "stop_move":
            inside = (tab_t >= ts[0]) & (tab_t <= ts[-1])
            if inside.sum() < 3 or np.median(np.diff(tab_t[inside])) > DENSE_TABLE_S:
                skipped_moves += 1
                continue
            ref_rate[a:b] = np.interp(ts, tab_t, tab_rate)
            ref_angle[a:b] = np.interp(ts, tab_t, tab_pos)
        else:
            continue
        use[a:b] = True
        if np.isfinite(seg_v):
            supply[a:b] = seg_v
        # a multi-position window is a static window to the model (and the noise estimate)
        seg_kind = "static" if kind == "position_static" else kind
        segments.append(Segment(seg_kind, float(t_fix[a]), float(t_fix[b - 1]) + 1e-9,
                                str(segs["condition"][k])))
    if skipped_moves:
        notes.append(
            f"{skipped_moves} stop moves left out: the table log is too sparse to follow them"
        )
    missing_v = ~np.isfinite(supply)
    if np.any(missing_v & use):
        if not sup_t.size:
            raise ValueError(f"{folder}: no supply voltage in the segments or the supply log")
        j = np.clip(np.searchsorted(sup_t, t_sta, side="right") - 1, 0, sup_t.size - 1)
        supply[missing_v] = sup_v[j][missing_v]
    if use.sum() < 100:
        raise ValueError(
            f"{folder}: fewer than 100 samples fall in analysed windows; was the run complete?"
        )
    notes.append("reference known only inside analysed windows; transitions are not used")
    return Trajectory(
        time_s=t_fix[use],
        gyro_dps=gyro[use],
        ref_rate_dps=ref_rate[use],
        ref_angle_deg=ref_angle[use],
        temp_c=temp[use],
        supply_v=supply[use],
        time_since_power_on_s=np.maximum(t_sta[use] - power_on_s, 0.0),
        segments=tuple(segments),
        source=str(folder),
        serial=record.dut.serial,
        notes=tuple(notes),
    )
