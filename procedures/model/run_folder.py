"""Load a run folder (record.json + raw.h5) into a Trajectory for the discrepancy workflow.

With hardware sync (the fixture latches the table's encoder count into every sample frame,
drivers/fixture_protocol.py) every sample has its own reference: the table angle at the
sample, and the mean rate since the previous sample (two latches over the fixture's own
time step), which is what the part's sample is. Then the whole record is used: analysed
windows keep their kind, everything between them (accelerations, settling, thermal soaks)
is a `transition`, so effects that show only while the rate changes (sensor lag) are seen.
Left out: verify windows and compensated samples (the part applies its new correction
there), the first sample after a lost frame, and samples between analysed windows while
the supply log says the supply changed.

Without latched encoder counts (a fixture without its encoder input, or an older run
folder) only samples inside windows with a known reference are used: static, stabilise,
stop_static, position_static (rate 0; the last from the optional multi-position step,
loaded as static) and plateau (the window's reference rate; angle advancing from the
nearest snapshot). Stop moves are used only where the table log is dense enough to follow
the motion (< 0.1 s between rows).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from common.h5_input import open_h5
from drivers.protocols import ENCODER_MODULO, SampleStatus
from procedures.model.data import load_csv
from procedures.model.trajectory import FloatArray, Segment, Trajectory
from procedures.runtime.rawdata import RawDataError, read_raw
from procedures.runtime.record import RAW_DATA_FILE, RECORD_FILE, read_record, three_axis_block

log = logging.getLogger(__name__)

STATIC_KINDS = ("static", "stabilise", "stop_static", "position_static")
# a rate plateau as the rate table writes it, or as the ramp does (eol-ramp: the table at a
# constant rate while the die heats or cools; the model's temperature follows each sample)
PLATEAU_KINDS = ("plateau", "ramp_plateau")
DENSE_TABLE_S = 0.1
MIN_LATCHED_FRACTION = 0.9  # below this, the record is read as having no hardware sync
SUPPLY_STEADY_V = 0.01  # neighbouring supply readings closer than this: supply unchanged
SUPPLY_MARGIN_S = 0.25  # around a change of supply: station-time estimates are this uncertain
AT_REST_DPS = 0.01
MAX_SCALE_MISMATCH = 1e-3  # latched angle vs the table's own position, relative
SEQ_MODULO = 1 << 16
# samples the model cannot use: the part's own correction applied, clipped or out of range,
# temperature sensor invalid, supply below the part's minimum
UNUSABLE = int(
    SampleStatus.COMPENSATED
    | SampleStatus.OVER_RANGE
    | SampleStatus.SATURATED
    | SampleStatus.TEMP_INVALID
    | SampleStatus.SUPPLY_LOW
)


MIN_SAMPLES = 100  # fewer samples than this: nothing to analyse


@dataclass(frozen=True)
class RunFolderChoice:
    """The run folder the data is read from, and how it was picked under a results folder."""

    folder: Path
    serial: str | None = None  # the part asked for (--dut), if any
    candidates: int = 1  # run folders of that part (or in total) found there
    # newer run folders of the part passed over, each with why it holds nothing to analyse
    skipped: tuple[tuple[str, str], ...] = ()

    @property
    def note(self) -> str | None:
        """Which of several run folders of the part was used (and which newer ones were
        skipped, and why), or None if there was one."""
        if self.candidates <= 1:
            return None
        if not self.skipped:
            return (
                f"{self.candidates} run folders for {self.serial}; the newest, "
                f"{self.folder.name}, was used"
            )
        why = "; ".join(f"{name} ({reason})" for name, reason in self.skipped)
        return (
            f"{self.candidates} run folders for {self.serial}; the newest usable one, "
            f"{self.folder.name}, was used; skipped, newer but with nothing to analyse: {why}"
        )


def find_run_folder(path: Path, dut: str | None) -> RunFolderChoice:
    """The run folder itself, or the newest usable run folder of `dut` under a results
    folder (newest = last by folder name: run folder names start with their UTC start time;
    usable = its raw data holds samples to analyse: a run that ended in ERROR before it
    measured anything is skipped, and the choice says so)."""
    if (path / RECORD_FILE).exists():
        return RunFolderChoice(path, dut)
    candidates = sorted((p.parent for p in path.glob(f"*/{RECORD_FILE}")), key=lambda p: p.name)
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
    skipped: list[tuple[str, str]] = []
    for folder in reversed(candidates):
        why = unusable_reason(folder)
        if why is None:
            return RunFolderChoice(folder, dut, len(candidates), tuple(skipped))
        skipped.append((folder.name, why))
    listed = "; ".join(f"{name} ({reason})" for name, reason in skipped)
    raise ValueError(
        f"{path}: no run folder{f' of {dut}' if dut else ''} holds data to analyse: {listed}; "
        "run the part again"
    )


def unusable_reason(folder: Path) -> str | None:
    """Why a run folder holds nothing to analyse (None if it does), from its record's
    verdict and the size of its raw data, without reading the samples themselves."""
    try:
        record = read_record(folder)
        verdict = str(record.verdict.value)
        fitted_xyz = three_axis_block(record) is not None
    except (ValueError, AttributeError):
        verdict, fitted_xyz = "unknown", False
    path = folder / RAW_DATA_FILE
    if not path.exists():
        return f"verdict {verdict}, no {RAW_DATA_FILE}"
    try:
        n, windows, xyz = raw_sizes(path)
    except (OSError, KeyError, ValueError) as exc:
        return f"verdict {verdict}, {RAW_DATA_FILE} cannot be read ({exc})"
    if n < MIN_SAMPLES:
        return f"verdict {verdict}, {n} samples"
    if windows == 0:
        return f"verdict {verdict}, no analysed window"
    if xyz and not fitted_xyz:  # a three-axis part is analysed with its run's fit
        return f"verdict {verdict}, a three-axis run that ended before its fit"
    return None


def raw_sizes(path: Path) -> tuple[int, int, bool]:
    """(samples, analysed windows, whether it holds a three-axis part's per-axis samples)
    of a raw data file, from the datasets' shapes alone (a truncated file is refused at once,
    ValueError, by the bounded opener: HDF5 itself retries it for minutes)."""
    with open_h5(path) as f:
        n = int(f["samples/time_s"].shape[0]) if "samples/time_s" in f else 0
        windows = int(f["segments/kind"].shape[0]) if "segments/kind" in f else 0
        return n, windows, "samples_xyz" in f


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
    return load_run_folder(find_run_folder(path, dut).folder, dut)


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


@dataclass(frozen=True)
class _Record:
    """The raw data of one run, samples sorted by fixture time (duplicates dropped)."""

    folder: Path
    serial: str
    attrs: dict[str, object]
    t_fix: FloatArray
    t_sta: FloatArray
    seq: NDArray[np.int64]
    gyro: FloatArray
    temp: FloatArray
    status: NDArray[np.int64]
    encoder: NDArray[np.int64]
    tab_t: FloatArray
    tab_pos: FloatArray
    tab_rate: FloatArray
    sup_t: FloatArray
    sup_v: FloatArray
    segs: dict[str, NDArray[np.generic]]

    @property
    def power_on_s(self) -> float:
        return float(self.sup_t.min()) if self.sup_t.size else float(self.t_best[0])

    @cached_property
    def t_best(self) -> FloatArray:
        """Station time of each sample from the fixture clock with the smallest offset seen
        (transport latency only ever adds to it), not the estimate current at ingest."""
        return self.t_fix + float(np.min(self.t_sta - self.t_fix))


def _read(folder: Path, dut: str | None) -> _Record:
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
    if s["time_s"].size < MIN_SAMPLES:
        raise ValueError(f"{folder}: the raw data holds only {s['time_s'].size} samples")
    order = np.argsort(s["time_s"], kind="stable")
    t_sorted = s["time_s"][order]
    idx = order[np.concatenate([[True], np.diff(t_sorted) > 0])]
    tab = raw["table"]
    tab_order = np.argsort(tab["station_time_s"])
    sup = raw["supply"]
    sup_order = np.argsort(sup["station_time_s"])
    return _Record(
        folder=folder,
        serial=record.dut.serial,
        attrs=raw.attrs,
        t_fix=s["time_s"][idx],
        t_sta=s["station_time_s"][idx],
        seq=s["seq"][idx].astype(np.int64),
        gyro=s["rate_dps"][idx],
        temp=s["temp_c"][idx],
        status=s["status"][idx].astype(np.int64),
        encoder=s["encoder_counts"][idx].astype(np.int64),
        tab_t=tab["station_time_s"][tab_order],
        tab_pos=tab["position_deg"][tab_order],
        tab_rate=tab["rate_dps"][tab_order],
        sup_t=sup["station_time_s"][sup_order],
        sup_v=sup["voltage_v"][sup_order],
        segs=raw["segments"],
    )


def load_run_folder(folder: Path, dut: str | None = None) -> Trajectory:
    rec = _read(folder, dut)
    latched = (rec.status & int(SampleStatus.ENCODER_LATCHED)) != 0
    cpr = rec.attrs.get("encoder_counts_per_rev")
    if latched.mean() < MIN_LATCHED_FRACTION or not isinstance(cpr, int | float) or cpr <= 0:
        return _windowed_trajectory(rec)
    angle = _latched_angle(rec, float(cpr))
    frame = _table_frame(rec, angle)
    if isinstance(frame, str):  # the latched counts do not match the table: say why
        return _windowed_trajectory(rec, (frame,))
    return _latched_trajectory(rec, latched, angle + frame)


def _segment_list(rec: _Record) -> list[tuple[str, int, int, int]]:
    """(kind, first, stop, segment row) of every analysed window, in time order, each
    sample in at most one window (the first keeps overlapping samples)."""
    segs = rec.segs
    out = []
    taken = np.zeros(rec.t_fix.size, dtype=bool)
    for k in np.argsort(segs["start_s"]):
        a = int(np.searchsorted(rec.t_fix, segs["start_s"][k], side="left"))
        b = int(np.searchsorted(rec.t_fix, segs["end_s"][k], side="right"))
        if b - a < 3:
            continue
        if np.any(taken[a:b]):
            a = a + int(np.argmin(taken[a:b])) if not np.all(taken[a:b]) else b
            if b - a < 3:
                continue
        taken[a:b] = True
        out.append((str(segs["kind"][k]), a, b, int(k)))
    return out


def _model_kind(kind: str) -> str:
    """The window's kind to the model without hardware sync: a multi-position window is
    static, a ramp's plateau a plateau (its reference the window's rate, as the rate
    table's)."""
    if kind == "position_static":
        return "static"
    return "plateau" if kind in PLATEAU_KINDS else kind


def _latched_angle(rec: _Record, cpr: float) -> FloatArray:
    """Table angle at each sample from the latched counts (u32 wraps undone), relative to
    the first sample."""
    step = np.diff(rec.encoder)
    step = (step + ENCODER_MODULO // 2) % ENCODER_MODULO - ENCODER_MODULO // 2
    return np.concatenate([[0], np.cumsum(step)]) * (360.0 / cpr)


def _table_frame(rec: _Record, angle: FloatArray) -> float | str:
    """Offset from the latched angle to the table's own position frame (zeroed by the
    station), from the table log rows at rest; or why the two do not agree (wrong counts
    per revolution, encoder channels swapped)."""
    rest = np.abs(rec.tab_rate) < AT_REST_DPS
    if not rest.any():
        return 0.0
    j = np.clip(np.searchsorted(rec.t_best, rec.tab_t[rest]), 0, rec.t_best.size - 1)
    pos, lat = rec.tab_pos[rest], angle[j]
    if np.ptp(lat) > 30.0:
        slope = float(np.polyfit(lat, pos, 1)[0])
        if abs(slope - 1.0) > MAX_SCALE_MISMATCH:
            return (
                f"the latched encoder angle does not follow the table's position (slope "
                f"{slope:.5f}, expected 1): check the fixture's encoder input (counts per "
                "revolution, A/B channels); transitions are not used"
            )
    diff = np.radians(pos - lat)  # circular mean: safe where the offset is near 180 deg
    return float(np.degrees(np.arctan2(np.mean(np.sin(diff)), np.mean(np.cos(diff)))))


def _latched_trajectory(rec: _Record, latched: NDArray[np.bool_], angle: FloatArray) -> Trajectory:
    n = rec.t_fix.size
    dt = np.diff(rec.t_fix)
    period = float(np.median(dt))
    # mean rate since the previous sample: valid only between consecutive frames (sequence
    # and fixture time agree) that both carry a latch
    pair_ok = (
        latched[1:]
        & latched[:-1]
        & (np.diff(rec.seq) % SEQ_MODULO == 1)
        & (dt > 0.5 * period)
        & (dt < 1.5 * period)
    )
    ref_rate = np.zeros(n)
    ref_rate[1:] = np.diff(angle) / dt
    use = np.concatenate([[False], pair_ok])
    unusable = (rec.status & UNUSABLE) != 0
    use &= ~unusable

    supply = np.full(n, np.nan)
    segments: list[Segment] = []
    for kind, a, b, k in _segment_list(rec):
        if kind == "verify":
            use[a:b] = False
            continue
        seg_v = float(rec.segs["supply_v"][k])
        if np.isfinite(seg_v):
            supply[a:b] = seg_v
        # (a ramp's plateau keeps its kind here: its latched reference carries the encoder's
        # quantisation, which the noise's Allan deviation over constant inputs would take
        # for white noise of the block means)
        seg_kind = "static" if kind in STATIC_KINDS else kind
        segments.append(Segment(seg_kind, float(rec.t_fix[a]),
                                float(rec.t_fix[b - 1]) + 1e-9,
                                str(rec.segs["condition"][k])))
    notes = []
    missing = ~np.isfinite(supply)
    if np.any(missing & use):
        logged_v, steady = _logged_supply(rec)
        supply[missing] = logged_v[missing]
        dropped = missing & use & ~steady
        use &= ~dropped
        if dropped.any():
            k = int(dropped.sum())
            notes.append(
                f"{k} sample{'s' if k != 1 else ''} between windows left out: the supply "
                "changed there or is not logged"
            )
    if use.sum() < 100:
        raise ValueError(
            f"{rec.folder}: fewer than 100 samples have a latched table reference; "
            "was the run complete?"
        )
    if unusable.any():
        k = int(unusable.sum())
        notes.append(
            f"{k} sample{'s' if k != 1 else ''} left out: compensated, clipped, over range, "
            "temperature invalid or supply low"
        )
    k = int(n - pair_ok.sum())  # the record's first sample has no previous latch either
    notes.append(
        "reference from the table encoder latched into every sample (hardware sync): "
        f"windows and transitions used; {k} sample{'s' if k != 1 else ''} without a "
        "previous latch left out (the first sample, and any after a lost frame)"
    )
    return Trajectory(
        time_s=rec.t_fix[use],
        gyro_dps=rec.gyro[use],
        ref_rate_dps=ref_rate[use],
        ref_angle_deg=angle[use],
        temp_c=rec.temp[use],
        supply_v=supply[use],
        time_since_power_on_s=np.maximum(rec.t_best[use] - rec.power_on_s, 0.0),
        segments=tuple(segments),
        source=str(rec.folder),
        serial=rec.serial,
        notes=tuple(notes),
    )


def _logged_supply(rec: _Record) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Supply at each sample from the supply log (NaN before the first reading), and whether
    it is known there: not between two readings that differ (the engine logs one just
    before and one just after every change of setting), nor within SUPPLY_MARGIN_S of such
    a change. After the last reading the supply is unchanged."""
    t = rec.t_best
    if not rec.sup_t.size:
        return np.full(t.size, np.nan), np.zeros(t.size, dtype=bool)
    j = np.searchsorted(rec.sup_t, t, side="right")
    value = np.where(j > 0, rec.sup_v[np.clip(j - 1, 0, rec.sup_v.size - 1)], np.nan)
    known = j > 0
    changes = np.flatnonzero(np.abs(np.diff(rec.sup_v)) >= SUPPLY_STEADY_V)
    for i in changes:
        lo, hi = rec.sup_t[i] - SUPPLY_MARGIN_S, rec.sup_t[i + 1] + SUPPLY_MARGIN_S
        known[int(np.searchsorted(t, lo)) : int(np.searchsorted(t, hi, side="right"))] = False
    return value, known


def _windowed_trajectory(rec: _Record, why: tuple[str, ...] = ()) -> Trajectory:
    t_fix, t_sta = rec.t_fix, rec.t_sta
    tab_t, tab_pos, tab_rate = rec.tab_t, rec.tab_pos, rec.tab_rate
    notes = list(why)
    if not rec.sup_t.size:
        notes.append("no supply log: time since power-on counted from the first sample")
    use = np.zeros(t_fix.size, dtype=bool)
    ref_rate = np.zeros(t_fix.size)
    ref_angle = np.zeros(t_fix.size)
    supply = np.full(t_fix.size, np.nan)
    segments: list[Segment] = []
    skipped_moves = 0
    for kind, a, b, k in _segment_list(rec):
        if kind == "verify":
            continue
        ts = t_sta[a:b]
        seg_v = float(rec.segs["supply_v"][k])
        if kind in STATIC_KINDS:
            ref_rate[a:b] = 0.0
            ref_angle[a:b] = _static_angle(tab_t, tab_pos, tab_rate, float(ts[0]), float(ts[-1]))
        elif kind in PLATEAU_KINDS:
            rate = float(rec.segs["ref_rate_dps"][k])
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
        use[a:b] = (rec.status[a:b] & UNUSABLE) == 0  # clipped, compensated, ...
        if np.isfinite(seg_v):
            supply[a:b] = seg_v
        segments.append(Segment(_model_kind(kind), float(t_fix[a]), float(t_fix[b - 1]) + 1e-9,
                                str(rec.segs["condition"][k])))
    if skipped_moves:
        notes.append(
            f"{skipped_moves} stop move{'s' if skipped_moves != 1 else ''} left out: the "
            "table log is too sparse to follow "
            + ("them" if skipped_moves != 1 else "it")
        )
    missing_v = ~np.isfinite(supply)
    if np.any(missing_v & use):
        if not rec.sup_t.size:
            raise ValueError(f"{rec.folder}: no supply voltage in the segments or the supply log")
        supply[missing_v] = _logged_supply(rec)[0][missing_v]
        use &= np.isfinite(supply)
    if use.sum() < 100:
        raise ValueError(
            f"{rec.folder}: fewer than 100 samples fall in analysed windows; was the run "
            "complete?"
        )
    notes.append(
        "no latched encoder counts (hardware sync): reference known only inside analysed "
        "windows; transitions are not used"
    )
    return Trajectory(
        time_s=t_fix[use],
        gyro_dps=rec.gyro[use],
        ref_rate_dps=ref_rate[use],
        ref_angle_deg=ref_angle[use],
        temp_c=rec.temp[use],
        supply_v=supply[use],
        time_since_power_on_s=np.maximum(t_sta[use] - rec.power_on_s, 0.0),
        segments=tuple(segments),
        source=str(rec.folder),
        serial=rec.serial,
        notes=tuple(notes),
    )
