"""Raw data file of a run: `raw.h5` in the run folder, written incrementally.

Self-describing HDF5 (h5py): every dataset carries a `units` attribute, the root carries the
format name, part serial and run id. The file is opened in single-writer/multiple-reader mode
and flushed after every append, so a run killed mid-way leaves a readable file holding
everything measured up to the last flush.

Layout (all 1-D, resizable, appended together within a group so rows line up):

    /samples   time_s (fixture clock, s)   seq   rate_code   temp_code   status
               rate_dps   temp_c   station_time_s (station clock estimate of the sample time)
               encoder_counts (the table's encoder count latched by the fixture at the
               sample, raw u32; valid where status has ENCODER_LATCHED; the root attribute
               encoder_counts_per_rev scales it)
    /table     station_time_s   controller_time_s   encoder_counts   position_deg   rate_dps
               status
    /chamber   station_time_s   setpoint_c   temp_c
    /supply    station_time_s   voltage_v   current_a
    /segments  one row per analysed window: condition, kind (static | plateau | stop_move |
               stop_static | verify | stabilise), index, start_s, end_s (fixture clock),
               ref_rate_dps, ref_angle_deg, temp_setpoint_c, supply_v
    /events    station_time_s, text
    /samples_xyz  three-axis parts only (a single-axis file has no such group): one row per
               /samples row, in the same order: rate_x_code .. rate_z_code and accel_x_code ..
               accel_z_code (the wire codes) and rate_x_dps .. rate_z_dps, accel_x_mps2 ..
               accel_z_mps2 (decoded with the product's codes); /samples' rate_code and
               rate_dps then hold the x axis

Readers use `read_raw`, which returns plain numpy arrays per group; the run itself reads its
older sample windows back with `RawDataWriter.read_window`.
"""

from __future__ import annotations

import errno
import hashlib
import logging
import os
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from common.h5_input import H5InputError, one_line, open_h5
from procedures.runtime.record import StorageError, storage_error

log = logging.getLogger(__name__)

FORMAT = "gyrocal-raw/1"
CHUNK_CACHE_BYTES = 1 << 16  # two 4096-row chunks of 8-byte values

# free space a raw data file leaves on its disk: room for HDF5 to close it cleanly and for
# record.json (tens of kB) after it
RESERVE_BYTES = 1 << 20

_STR = h5py.string_dtype("utf-8")

GROUPS: dict[str, dict[str, tuple[Any, str]]] = {
    "samples": {
        "time_s": ("f8", "s"),
        "seq": ("i8", "1"),
        "rate_code": ("i4", "counts"),
        "temp_code": ("i4", "counts"),
        "status": ("u1", "bits"),
        "rate_dps": ("f8", "deg/s"),
        "temp_c": ("f8", "C"),
        "station_time_s": ("f8", "s"),
        "encoder_counts": ("i8", "counts"),
    },
    "table": {
        "station_time_s": ("f8", "s"),
        "controller_time_s": ("f8", "s"),
        "encoder_counts": ("i8", "counts"),
        "position_deg": ("f8", "deg"),
        "rate_dps": ("f8", "deg/s"),
        "status": ("u2", "bits"),
    },
    "chamber": {
        "station_time_s": ("f8", "s"),
        "setpoint_c": ("f8", "C"),
        "temp_c": ("f8", "C"),
    },
    "supply": {
        "station_time_s": ("f8", "s"),
        "voltage_v": ("f8", "V"),
        "current_a": ("f8", "A"),
    },
    "segments": {
        "condition": (_STR, ""),
        "kind": (_STR, ""),
        "index": ("i4", "1"),
        "start_s": ("f8", "s"),
        "end_s": ("f8", "s"),
        "ref_rate_dps": ("f8", "deg/s"),
        "ref_angle_deg": ("f8", "deg"),
        "temp_setpoint_c": ("f8", "C"),
        "supply_v": ("f8", "V"),
    },
    "events": {
        "station_time_s": ("f8", "s"),
        "text": (_STR, ""),
    },
}


_XYZ = "xyz"
# groups only some files have: the writer creates them when asked (`extra_groups`), readers
# return them when the file has them
EXTRA_GROUPS: dict[str, dict[str, tuple[Any, str]]] = {
    "samples_xyz": {
        **{f"rate_{a}_code": ("i4", "counts") for a in _XYZ},
        **{f"accel_{a}_code": ("i4", "counts") for a in _XYZ},
        **{f"rate_{a}_dps": ("f8", "deg/s") for a in _XYZ},
        **{f"accel_{a}_mps2": ("f8", "m/s^2") for a in _XYZ},
    },
}

# Columns added after the format's first files: a file without them reads as all zeros
# (for encoder_counts, with ENCODER_LATCHED clear in status, that means "not latched").
OPTIONAL_COLUMNS = {("samples", "encoder_counts")}


class RawDataError(ValueError):
    """The raw data file is missing, unreadable or not of this format."""


class RawDataWriter:
    """Appends rows to the groups of a new raw data file; flushes after every append."""

    def __init__(
        self, path: Path, attrs: Mapping[str, Any], extra_groups: Sequence[str] = ()
    ) -> None:
        self.path = path
        unknown = set(extra_groups) - set(EXTRA_GROUPS)
        if unknown:
            raise ValueError(f"raw data: unknown groups {sorted(unknown)}")
        # every group is created now: no dataset can be added once readers may attach (SWMR)
        self._groups = {**GROUPS, **{g: EXTRA_GROUPS[g] for g in extra_groups}}
        # the first write that failed (disk full, read-only, I/O error): every later call
        # raises it again, and the HDF5 file is already closed (see _fail)
        self.failure: StorageError | None = None
        # a small chunk cache per dataset (HDF5's default is 1 MiB each, 32 datasets a file):
        # rows are appended, so only the chunk being filled needs to stay in memory
        try:
            self._file = h5py.File(path, "w", libver="latest", rdcc_nbytes=CHUNK_CACHE_BYTES)
        except (OSError, RuntimeError) as exc:
            raise storage_error(path, exc) from exc
        with self._writing():
            self._create(attrs)

    def _create(self, attrs: Mapping[str, Any]) -> None:
        self._file.attrs["format"] = FORMAT
        for key, value in attrs.items():
            self._file.attrs[key] = value
        # the datasets by group and column, looked up once (h5py's lookups cost more than
        # writing a batch of rows)
        self._datasets: dict[str, dict[str, Any]] = {}
        self._rows: dict[str, int] = {}  # rows written per group (every column alike)
        for group_name, columns in self._groups.items():
            group = self._file.create_group(group_name)
            self._datasets[group_name] = {}
            self._rows[group_name] = 0
            for column, (dtype, units) in columns.items():
                ds = group.create_dataset(
                    column, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(4096,)
                )
                ds.attrs["units"] = units
                self._datasets[group_name][column] = ds
        self._file.swmr_mode = True
        self._file.flush()

    def append(self, group: str, **columns: Any) -> None:
        """Append rows; every column of the group must be given, all of one length (an
        optional column left out is written as zeros)."""
        if group not in self._groups:
            raise ValueError(f"raw data group {group!r} is not in this file")
        expected = self._groups[group]
        optional = {c for g, c in OPTIONAL_COLUMNS if g == group and c not in columns}
        if optional and columns:
            rows = len(np.atleast_1d(np.asarray(next(iter(columns.values())))))
            columns = {**columns, **{c: np.zeros(rows, dtype=expected[c][0]) for c in optional}}
        missing = set(expected) - set(columns)
        extra = set(columns) - set(expected)
        if missing or extra:
            raise ValueError(
                f"raw data group {group!r}: missing {sorted(missing)}, unknown {sorted(extra)}"
            )
        arrays = {k: np.atleast_1d(np.asarray(v)) for k, v in columns.items()}
        lengths = {a.shape[0] for a in arrays.values()}
        if len(lengths) != 1:
            raise ValueError(f"raw data group {group!r}: columns of different lengths {lengths}")
        (n,) = lengths
        if n == 0:
            return
        with self._writing():
            self._room_for(sum(a.nbytes if a.dtype != object else 64 * n
                               for a in arrays.values()))
            datasets = self._datasets[group]
            old = self._rows[group]
            for column, values in arrays.items():
                ds = datasets[column]
                ds.resize((old + n,))
                if expected[column][0] is _STR:
                    ds[old : old + n] = [str(v) for v in values]
                else:
                    ds[old : old + n] = values
            self._rows[group] = old + n
            self._file.flush()

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """Every HDF5 write goes through here: a failure (h5py raises OSError or
        RuntimeError) becomes one StorageError naming the file, kept in `failure`."""
        if self.failure is not None:
            raise self.failure
        try:
            yield
        except StorageError as exc:  # _room_for: refused before the disk did
            self._fail(exc, disk_refused=False)
            raise
        except (OSError, RuntimeError) as exc:
            error = storage_error(self.path, exc)
            self._fail(error, disk_refused=True)
            raise error from exc

    def _room_for(self, nbytes: int) -> None:
        """Refuse a write that would leave less than RESERVE_BYTES free on the disk: HDF5
        closes the file cleanly (readable) only while it can still write its metadata, and
        record.json must still fit after it."""
        try:
            st = os.statvfs(self.path.parent)
        except OSError:
            return  # the write itself will say what is wrong
        if st.f_bavail * st.f_frsize < nbytes + RESERVE_BYTES:
            raise StorageError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))

    def _fail(self, error: StorageError, disk_refused: bool) -> None:
        """Close the file after a failed write without letting HDF5 write again. After a
        failed write HDF5's close fails too and the library crashes the process at exit
        (SIGSEGV); so a disk that refused (ENOSPC, EROFS, EIO) gets its descriptor pointed at
        /dev/null first, and HDF5 closes cleanly. The file keeps what the last successful
        flush wrote; a proactive refusal (_room_for) closes it properly instead."""
        self.failure = error
        if not self._file.id.valid:
            return
        if not disk_refused:
            try:  # still room for the metadata (_room_for refused in time): a clean close
                self._file.close()
                return
            except (OSError, RuntimeError):
                pass
        try:
            fd = self._file.id.get_vfd_handle()
            null = os.open(os.devnull, os.O_RDWR)
            try:
                os.dup2(null, fd)
            finally:
                os.close(null)
            self._file.close()
        except (OSError, RuntimeError, ValueError) as exc:
            log.error("%s: raw data file left open after a failed write: %s", self.path, exc)

    def read_window(
        self, group: str, key: str, start: float, end: float
    ) -> dict[str, NDArray[Any]]:
        """The rows written so far whose `key` column (sorted ascending, e.g. samples'
        time_s) lies in [start, end): every column of the group, read back from the file
        (only the window and a binary search's few values come into memory)."""
        if self.failure is not None:
            raise self.failure
        g = self._file[group]
        ds = g[key]
        i0, i1 = _bisect(ds, start), _bisect(ds, end)
        return {column: g[column][i0:i1] for column in self._groups[group]}

    def row_of(self, group: str, key: str, value: float) -> int:
        """The first row whose sorted `key` column is not below `value`."""
        if self.failure is not None:
            raise self.failure
        return _bisect(self._file[group][key], value)

    def read_rows(self, group: str, start: int, end: int) -> dict[str, NDArray[Any]]:
        """Rows [start, end) written so far of every column of `group`."""
        if self.failure is not None:
            raise self.failure
        g = self._file[group]
        return {column: g[column][start:end] for column in self._groups[group]}

    def has_group(self, group: str) -> bool:
        return group in self._groups

    def close(self) -> None:
        """Flush and close; a failed write (now or before) raises StorageError, and the
        file is closed in every case."""
        if self.failure is not None:
            raise self.failure
        if self._file.id.valid:
            with self._writing():
                self._file.flush()
                self._file.close()

    def __enter__(self) -> RawDataWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _bisect(ds: Any, value: float, block: int = 4096) -> int:
    """First index of the sorted 1-D dataset `ds` whose value is not below `value`: a binary
    search over blocks (one read each), then one block read."""
    lo, hi = 0, ds.shape[0]
    while hi - lo > block:
        mid = (lo + hi) // 2
        if ds[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo + int(np.searchsorted(ds[lo:hi], value, side="left"))


@dataclass(frozen=True)
class RawData:
    attrs: dict[str, Any]
    groups: dict[str, dict[str, NDArray[Any]]]

    def __getitem__(self, group: str) -> dict[str, NDArray[Any]]:
        return self.groups[group]


def read_raw(path: Path) -> RawData:
    """Read a whole raw data file into memory; RawDataError says what is wrong if it can't."""
    if not path.exists():
        raise RawDataError(f"{path}: raw data file is missing")
    try:
        with open_h5(path) as f:
            if f.attrs.get("format") != FORMAT:
                raise RawDataError(
                    f"{path}: not a raw data file of format {FORMAT} "
                    f"(found {f.attrs.get('format')!r})"
                )
            attrs = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
            groups = {name: _read_group(path, f, name, columns)
                      for name, columns in GROUPS.items()}
            groups.update({name: _read_group(path, f, name, columns)
                           for name, columns in EXTRA_GROUPS.items() if name in f})
            return RawData(attrs=attrs, groups=groups)
    except RawDataError:
        raise
    except H5InputError as exc:
        raise RawDataError(str(exc)) from None
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
        raise RawDataError(f"{path}: raw data file cannot be read ({one_line(exc)})") from None


def _read_group(
    path: Path, f: Any, group_name: str, columns: dict[str, tuple[Any, str]]
) -> dict[str, NDArray[Any]]:
    if group_name not in f:
        raise RawDataError(f"{path}: group /{group_name} is missing")
    g = f[group_name]
    out: dict[str, NDArray[Any]] = {}
    for column, (dtype, _units) in columns.items():
        if column not in g and (group_name, column) in OPTIONAL_COLUMNS:
            rows = next(iter(g.values())).shape[0] if len(g) else 0
            out[column] = np.zeros(rows, dtype=dtype)
            continue
        if column not in g:
            raise RawDataError(f"{path}: dataset /{group_name}/{column} is missing")
        data = g[column][()]
        if dtype is _STR:
            data = np.asarray(
                [d.decode() if isinstance(d, bytes) else str(d) for d in data], dtype=object
            )
        out[column] = data
    return out


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
