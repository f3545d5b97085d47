"""Recorded part output for the replay driver: a run folder's raw.h5, or a CSV.

A raw.h5 (format gyrocal-raw/1, written by `procedures.runtime.rawdata`) gives the samples exactly
as
the fixture sent them: fixture time, sequence number, rate and temperature codes, status and
the latched encoder count; its /supply log gives the supply voltage at each sample (for the
part's compensation). It is read here with h5py directly, so drivers need nothing from
procedures (dependencies point station -> procedures -> drivers).

A CSV has a header row and the columns `time_s`, `rate_dps`, `temp_c` and optionally
`supply_v` (other columns are ignored); its engineering units are turned into codes with the
product's code format (`drivers.part_codes.CodeFormat`), the same conversion the station uses
to read them back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from common.csv_rows import CsvInputError, csv_rows, shown
from common.h5_input import H5InputError, one_line, open_h5
from drivers.errors import ConnectionLost
from drivers.fixture_protocol import SEQ_MODULO
from drivers.part_codes import CodeFormat
from drivers.protocols import SampleStatus

RAW_FORMAT = "gyrocal-raw/1"  # procedures.runtime.rawdata.FORMAT (a test keeps the two equal)
RAW_DATA_FILE = "raw.h5"
CSV_COLUMNS = ("time_s", "rate_dps", "temp_c")
CSV_OPTIONAL_COLUMNS = ("supply_v",)
_RAW_COLUMNS = ("time_s", "seq", "rate_code", "temp_code", "status")
_CONVERSION_TOLERANCE_DPS = 1e-6


class RecordingError(ConnectionLost):
    """The recording to replay is missing, unreadable or not a recording of part output."""


@dataclass(frozen=True)
class Recording:
    """One part's recorded samples, in recording order (times strictly increasing)."""

    source: Path
    kind: str  # "raw.h5" or "csv"
    name: str  # the run id (raw.h5) or the file's name
    serial: str | None  # the part serial the recording names (None: a CSV names none)
    time_s: NDArray[np.float64]  # fixture time of each sample, s
    seq: NDArray[np.int64]
    rate_code: NDArray[np.int64]
    temp_code: NDArray[np.int64]
    status: NDArray[np.int64]
    encoder_counts: NDArray[np.int64]
    supply_v: NDArray[np.float64]  # NaN where the recording does not say

    def __len__(self) -> int:
        return int(self.time_s.size)

    @property
    def period_s(self) -> float:
        """The median time between samples (the recording's output period)."""
        if self.time_s.size < 2:
            return 0.01
        return float(np.median(np.diff(self.time_s)))

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])


def load_recording(path: Path, codes: CodeFormat) -> Recording:
    """The recording at `path`: a run folder (its raw.h5), a .h5 file or a .csv file."""
    path = Path(path)
    if path.is_dir():
        path = path / RAW_DATA_FILE
        if not path.exists():
            raise RecordingError(
                f"{path.parent}: no {RAW_DATA_FILE} in this folder; give a run folder, a "
                "raw.h5 or a CSV file as the replay's path"
            )
    if not path.exists():
        raise RecordingError(f"{path}: no such file; give a run folder, a raw.h5 or a CSV file")
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        recording = _load_raw(path, codes)
    elif suffix == ".csv":
        recording = _load_csv(path, codes)
    else:
        raise RecordingError(
            f"{path}: not a recording the replay can play (expected a run folder, a .h5 raw "
            "data file or a .csv file)"
        )
    _check_times(recording)
    return recording


# ---------------------------------------------------------------- raw.h5


def _load_raw(path: Path, codes: CodeFormat) -> Recording:
    try:
        with open_h5(path) as f:
            found = f.attrs.get("format")
            if found != RAW_FORMAT:
                raise RecordingError(
                    f"{path}: not a raw data file of format {RAW_FORMAT} (found {found!r})"
                )
            samples = _group(f, "samples", path)
            cols = {c: _dataset(samples, c, path) for c in (*_RAW_COLUMNS, "rate_dps")}
            n = cols["time_s"].size
            encoder = (
                _dataset(samples, "encoder_counts", path)
                if "encoder_counts" in samples
                else np.zeros(n, dtype=np.int64)
            )
            station_s = (
                _dataset(samples, "station_time_s", path)
                if "station_time_s" in samples
                else None
            )
            supply_v = _supply_at(f, station_s, n, path)
            attrs = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
    except RecordingError:
        raise
    except H5InputError as exc:
        raise RecordingError(str(exc)) from None
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
        raise RecordingError(f"{path}: raw data file cannot be read ({one_line(exc)})") from None
    if any(c.size != n for c in (*cols.values(), encoder)):
        raise RecordingError(f"{path}: the /samples columns have different lengths")
    _check_conversion(path, codes, cols["rate_code"], cols["rate_dps"])
    serial = attrs.get("serial")
    return Recording(
        source=path,
        kind="raw.h5",
        name=str(attrs.get("run_id") or path.parent.name),
        serial=str(serial) if serial else None,
        time_s=cols["time_s"].astype(np.float64),
        seq=cols["seq"].astype(np.int64),
        rate_code=cols["rate_code"].astype(np.int64),
        temp_code=cols["temp_code"].astype(np.int64),
        status=cols["status"].astype(np.int64),
        encoder_counts=encoder.astype(np.int64),
        supply_v=supply_v,
    )


def _group(f: h5py.File, name: str, path: Path) -> h5py.Group:
    group = f.get(name)
    if not isinstance(group, h5py.Group):
        raise RecordingError(f"{path}: group /{name} is missing")
    return group


def _dataset(group: h5py.Group, name: str, path: Path) -> NDArray[Any]:
    ds = group.get(name)
    if not isinstance(ds, h5py.Dataset):
        raise RecordingError(f"{path}: dataset {group.name}/{name} is missing")
    return np.asarray(ds[()])


def _supply_at(
    f: h5py.File, station_s: NDArray[Any] | None, n: int, path: Path
) -> NDArray[np.float64]:
    """The logged supply voltage at each sample's station time (NaN without a log)."""
    unknown = np.full(n, np.nan)
    group = f.get("supply")
    if station_s is None or not isinstance(group, h5py.Group):
        return unknown
    if "station_time_s" not in group or "voltage_v" not in group:
        return unknown
    log_s = _dataset(group, "station_time_s", path).astype(np.float64)
    log_v = _dataset(group, "voltage_v", path).astype(np.float64)
    keep = np.isfinite(log_s) & np.isfinite(log_v)
    if not keep.any():
        return unknown
    order = np.argsort(log_s[keep], kind="stable")
    return np.interp(station_s.astype(np.float64), log_s[keep][order], log_v[keep][order])


def _check_conversion(
    path: Path, codes: CodeFormat, rate_code: NDArray[Any], rate_dps: NDArray[Any]
) -> None:
    """The recording's deg/s must be what `codes` makes of its codes (else the replay's code
    format is not the product's, and compensation would be computed wrongly)."""
    if rate_code.size == 0:
        return
    ours = codes.rate_code_to_dps(rate_code)
    worst = int(np.argmax(np.abs(ours - rate_dps)))
    if not abs(ours[worst] - rate_dps[worst]) <= _CONVERSION_TOLERANCE_DPS * (
        1.0 + abs(float(rate_dps[worst]))
    ):
        raise RecordingError(
            f"{path}: sample {worst} has rate code {int(rate_code[worst])} recorded as "
            f"{float(rate_dps[worst]):.6g} deg/s, but the replay's code format reads it as "
            f"{float(ours[worst]):.6g} deg/s: give the replay the `codes:` of the product "
            "the recording was made with"
        )


# ---------------------------------------------------------------- CSV


def _load_csv(path: Path, codes: CodeFormat) -> Recording:
    try:
        numbered = list(csv_rows(path))  # bounded: common.csv_rows
    except CsvInputError as exc:
        raise RecordingError(str(exc)) from None
    if not numbered:
        raise RecordingError(f"{path}: empty CSV; it needs a header row {', '.join(CSV_COLUMNS)}")
    header = [h.strip() for h in numbered[0][1]]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise RecordingError(
            f"{path}: CSV header {shown(','.join(header))} lacks {', '.join(missing)}; "
            "the replay needs the "
            f"columns {', '.join(CSV_COLUMNS)} (and optionally {', '.join(CSV_OPTIONAL_COLUMNS)})"
        )
    data = numbered[1:]
    if not data:
        raise RecordingError(f"{path}: the CSV has a header but no samples")
    wanted = [c for c in (*CSV_COLUMNS, *CSV_OPTIONAL_COLUMNS) if c in header]
    index = {c: header.index(c) for c in wanted}
    values = {c: np.empty(len(data)) for c in wanted}
    for k, (line, row) in enumerate(data):
        for c in wanted:
            values[c][k] = _number(path, line, c, row, index[c])
    n = len(data)
    rate_code = codes.rate_dps_to_code(values["rate_dps"])
    status = np.zeros(n, dtype=np.int64)
    status[codes.rate_code_at_rail(rate_code)] |= SampleStatus.SATURATED
    return Recording(
        source=path,
        kind="csv",
        name=path.name,
        serial=None,
        time_s=values["time_s"],
        seq=np.arange(n, dtype=np.int64) % SEQ_MODULO,
        rate_code=rate_code,
        temp_code=codes.temp_c_to_code(values["temp_c"]),
        status=status,
        encoder_counts=np.zeros(n, dtype=np.int64),
        supply_v=values.get("supply_v", np.full(n, np.nan)),
    )


def _number(path: Path, line: int, column: str, row: list[str], i: int) -> float:
    text = row[i].strip() if i < len(row) else ""
    try:
        value = float(text)
    except ValueError:
        raise RecordingError(f"{path}:{line}: {column} is {shown(text)}, not a number") from None
    if not math.isfinite(value):
        raise RecordingError(f"{path}:{line}: {column} is {shown(text)}, not a finite number")
    return value


def _check_times(recording: Recording) -> None:
    t = recording.time_s
    if t.size == 0:
        raise RecordingError(f"{recording.source}: the recording holds no samples")
    if not np.isfinite(t).all():
        raise RecordingError(f"{recording.source}: the recording has non-finite times")
    steps = np.diff(t)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        raise RecordingError(
            f"{recording.source}: time_s does not increase at sample {i} "
            f"({t[i - 1]:.6f} s then {t[i]:.6f} s); a recording's times must strictly increase"
        )
