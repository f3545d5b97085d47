"""Load discrepancy data (a CSV or a run folder) into one typed Trajectory.

CSV (pinned columns): time_s, gyro_dps, ref_rate_dps, ref_angle_deg, temp_c, supply_v;
extra columns are allowed. An optional `segment_kind` column names each row's window
(static, plateau, stop_move, ...; trajectory.SEGMENT_KINDS, empty = transition); without it
the windows are inferred from the reference rate. `time_s` counts from power-on. Run
folders are read by run_folder.py.

Spreadsheet exports are read as they come: UTF-8 with or without a byte-order mark, fields
separated by ',', ';' or tab (whichever splits the header into the pinned columns; an Excel
`sep=;` first line is honoured), and in a ';' or tab file a decimal comma (1,5). Every value
must be a finite number: a `nan` or `inf` is refused with its line and column.
"""

from __future__ import annotations

import csv
import difflib
import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from common.csv_rows import check_csv_file, shown
from procedures.model.trajectory import SEGMENT_KINDS, FloatArray, Segment, Trajectory

CSV_COLUMNS = ("time_s", "gyro_dps", "ref_rate_dps", "ref_angle_deg", "temp_c", "supply_v")
STILL_RATE_DPS = 0.05
STEADY_ACCEL_DPS2 = 2.0
MIN_STEADY_S = 1.0
STOP_MOVE_MIN_DEG = 5.0
# The scale factor is fitted against changes of the reference rate: a record whose reference
# rate spans less than this (static only, or one constant rate) cannot be analysed.
MIN_RATE_SPAN_DPS = 1.0
DELIMITERS = (",", ";", "\t")
MAX_HEADER_CHARS = 4096
MAX_ABS_VALUE = 1e9  # any column: seconds, deg/s, deg, C, V
DELIMITER_NAMES = {",": "','", ";": "';'", "\t": "tab"}


def check_rate_varies(ref_rate_dps: FloatArray, source: str = "") -> None:
    """ValueError unless the reference rate changes enough to fit the scale factor apart
    from the bias (every analysis of a Trajectory needs that)."""
    rate = np.asarray(ref_rate_dps, dtype=float)
    rate = rate[np.isfinite(rate)]
    if rate.size == 0:
        return  # the Trajectory refuses non-finite columns itself
    span = float(np.max(rate) - np.min(rate))
    if span < MIN_RATE_SPAN_DPS:
        level = float(np.median(rate))
        raise ValueError(
            f"{source or 'data'}: the reference rate never changes (ref_rate_dps stays at "
            f"{level:.3g} deg/s, span {span:.3g} < {MIN_RATE_SPAN_DPS:g} deg/s): the scale "
            "factor cannot be fitted apart from the bias; the data needs rate plateaus or "
            "table moves (static-only records cannot be analysed)"
        )


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
    check_rate_varies(arr["ref_rate_dps"], source)
    t = arr["time_s"]
    same = np.flatnonzero(np.diff(t) == 0)
    if same.size:
        raise ValueError(
            f"{source or 'data'}: time_s {t[same[0]]:g} appears in more than one row; every "
            "sample needs its own time"
        )
    try:
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
    except ValueError as exc:
        raise ValueError(f"{source or 'data'}: {exc}") from exc


def segments_from_kinds(time_s: FloatArray, kinds: Sequence[str]) -> list[Segment]:
    """Runs of equal `segment_kind` labels become segments (an empty label: transition)."""
    unknown = sorted({str(k).strip() for k in kinds} - {"", *SEGMENT_KINDS})
    if unknown:
        raise ValueError(
            f"segment_kind {unknown} unknown; allowed: {', '.join(SEGMENT_KINDS)} "
            "or empty (transition)"
        )
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


def _header_delimiter(line: str) -> str:
    """The delimiter that splits the header into the most pinned columns (',' on a tie)."""

    def found(d: str) -> int:
        names = {f.strip() for f in next(csv.reader([line], delimiter=d), [])}
        return len(names & set(CSV_COLUMNS))

    return max(DELIMITERS, key=found)


def _number(text: str | None, decimal_comma: bool) -> float:
    """float() of a CSV field; ValueError if it is not a number."""
    if text is None:
        raise ValueError("missing")
    text = text.strip()
    if decimal_comma and "," in text and "." not in text:
        text = text.replace(",", ".")
    return float(text)


def load_csv(path: Path) -> Trajectory:
    """Read a discrepancy CSV; ValueError says which file, line and column is wrong."""
    if not path.exists():
        raise ValueError(f"{path}: file not found")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; give a CSV file")
    check_csv_file(path)  # a regular file of bounded size (a device never ends)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            return _read_csv(path, fh)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: not UTF-8 text (byte {exc.start}); save it as 'CSV UTF-8' from the "
            "spreadsheet"
        ) from None


def _csv_error(path: Path, line: int, exc: csv.Error) -> ValueError:
    return ValueError(
        f"{path}: line {line}: not a readable CSV ({exc}); a discrepancy CSV holds short "
        "numeric fields (and an optional segment_kind)"
    )


def _read_csv(path: Path, fh: TextIO) -> Trajectory:
    head = _read_header(path, fh)
    values: dict[str, list[float]] = {c: [] for c in CSV_COLUMNS}
    kinds: list[str] | None = [] if head.kind_col is not None else None
    lines: list[int] = []
    reader = csv.reader(fh, delimiter=head.delimiter)
    for row in _rows(reader, path, head.line):
        lineno = head.line + reader.line_num
        if not any(f.strip() for f in row):
            continue  # blank line, or a spreadsheet's empty row
        for c, value in head.values(path, lineno, row).items():
            values[c].append(value)
        lines.append(lineno)
        if kinds is not None:
            kinds.append(head.kind(path, lineno, row))
    if len(values["time_s"]) < 10:
        raise ValueError(f"{path}: only {len(values['time_s'])} rows; a whole run is needed")
    _check_own_times(path, np.asarray(values["time_s"]), lines)
    return trajectory_from_columns(values, kinds=kinds, source=str(path))


class _Header:
    """A discrepancy CSV's header: its fields, delimiter and line, and how it reads a row."""

    def __init__(self, fields: list[str], delimiter: str, line: int) -> None:
        self.fields, self.delimiter, self.line = fields, delimiter, line
        self.index = {c: fields.index(c) for c in CSV_COLUMNS}
        self.kind_col = fields.index("segment_kind") if "segment_kind" in fields else None
        self.decimal_comma = delimiter != ","

    def values(self, path: Path, lineno: int, row: list[str]) -> dict[str, float]:
        """The pinned columns of a row, each checked to be a plausible finite number."""
        short_of_pinned = any(i >= len(row) for i in self.index.values())  # named below
        if len(row) != len(self.fields) and not short_of_pinned:
            raise ValueError(
                f"{path}:{lineno}: {len(row):,} columns, but the header has "
                f"{len(self.fields)}; every row needs one value per header column"
            )
        out: dict[str, float] = {}
        for c, i in self.index.items():
            text = row[i] if i < len(row) else None
            out[c] = self._value(path, lineno, c, text, len(row))
        return out

    def _value(self, path: Path, lineno: int, c: str, text: str | None, n_row: int) -> float:
        try:
            value = _number(text, self.decimal_comma)
        except ValueError:
            if text is None:
                raise ValueError(
                    f"{path}: line {lineno}: column {c} is missing (the row has "
                    f"{n_row} fields, the header {len(self.fields)}); complete or remove "
                    "the row"
                ) from None
            raise ValueError(
                f"{path}: line {lineno}: column {c} is {shown(text)}, not a number"
            ) from None
        if not math.isfinite(value):
            raise ValueError(
                f"{path}: line {lineno}: column {c} is {shown(str(text))}, not a finite "
                "number; remove the row or give the measured value"
            )
        if abs(value) > MAX_ABS_VALUE:
            raise ValueError(
                f"{path}: line {lineno}: column {c} is {value:g}, beyond +/-"
                f"{MAX_ABS_VALUE:g}; not a plausible measurement"
            )
        return value

    def kind(self, path: Path, lineno: int, row: list[str]) -> str:
        """The row's segment_kind ('' when the column is short), checked to be a kind."""
        col = self.kind_col
        kind = row[col].strip() if col is not None and col < len(row) else ""
        if kind not in {"", *SEGMENT_KINDS}:
            close = difflib.get_close_matches(kind, SEGMENT_KINDS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(
                f"{path}: line {lineno}: column segment_kind is {shown(kind)}, not a window "
                f"kind{hint}; allowed: {', '.join(SEGMENT_KINDS)}, or empty for a "
                "transition"
            )
        return kind


def _read_header(path: Path, fh: TextIO) -> _Header:
    """The header line (after an Excel `sep=` hint), checked to hold each pinned column once."""
    first = fh.readline(MAX_HEADER_CHARS)
    if len(first) >= MAX_HEADER_CHARS and not first.endswith("\n"):
        raise ValueError(
            f"{path}: line 1 is longer than {MAX_HEADER_CHARS} characters; expected a header "
            f"{', '.join(CSV_COLUMNS)}"
        )
    header_line = 1
    delimiter = None
    if first.strip().lower().startswith("sep=") and len(first.strip()) == 5:  # Excel hint
        delimiter = first.strip()[4]
        first = fh.readline(MAX_HEADER_CHARS)
        header_line = 2
    if not first.strip():
        raise ValueError(f"{path}: empty file; expected a header {', '.join(CSV_COLUMNS)}")
    try:
        delimiter = delimiter or _header_delimiter(first)
        fields = [f.strip() for f in next(csv.reader([first], delimiter=delimiter), [])]
    except csv.Error as exc:
        raise _csv_error(path, header_line, exc) from None
    missing = [c for c in CSV_COLUMNS if c not in fields]
    if missing:
        raise ValueError(
            f"{path}: line {header_line}: columns {missing} are missing; the header must hold "
            f"{', '.join(CSV_COLUMNS)} (extra columns are allowed), separated by ',', ';' or tab"
        )
    twice = [c for c in (*CSV_COLUMNS, "segment_kind") if fields.count(c) > 1]
    if twice:
        raise ValueError(
            f"{path}: line {header_line}: columns {twice} appear more than once; keep one each"
        )
    return _Header(fields, delimiter, header_line)


def _check_own_times(path: Path, t: FloatArray, lines: list[int]) -> None:
    """ValueError naming both lines when two rows have the same time."""
    order = np.argsort(t, kind="stable")
    same = np.flatnonzero(np.diff(t[order]) == 0)
    if same.size:
        a, b = sorted((lines[order[same[0]]], lines[order[same[0] + 1]]))
        raise ValueError(
            f"{path}: line {b}: column time_s is {t[order[same[0]]]:g}, the same as on line "
            f"{a}; every row needs its own time (remove the repeated row)"
        )


def _rows(reader: Any, path: Path, header_line: int) -> Iterator[list[str]]:
    """The reader's rows; a csv.Error (a field over the size limit, ...) as a ValueError
    naming the line."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise _csv_error(path, header_line + reader.line_num, exc) from None
        yield row


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
