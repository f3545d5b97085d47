"""CSV input read with bounds (docs/input-bounds.md): a row whose column count differs from the
header is refused with file:line; a huge header, a huge file or a device (/dev/zero) is
refused before it is read through; every message is one line of bounded length."""

from __future__ import annotations

import contextlib
import io
import time
from pathlib import Path

import numpy as np
import pytest

from common.csv_rows import MAX_CSV_BYTES
from station.cli.main import main


def analyze(*args: str) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["analyze", *args])
    return code, err.getvalue()


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err[:2000]
    assert len(lines[0]) < 400, lines[0][:2000]
    return lines[0]


def static_csv(path: Path, rows: int = 200, extra: dict[int, str] | None = None) -> Path:
    t = np.arange(rows) * 0.01
    lines = ["time_s,rate_dps"] + [f"{x:.2f},{0.01 * np.sin(x):.6f}" for x in t]
    for line_no, text in (extra or {}).items():
        lines[line_no - 1] = text
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("row, columns", [("0.05,0.001,7", 3), ("0.05", 1),
                                          ("0.05,0.001" + ",9" * 1_000_000, 1_000_002)])
def test_a_row_with_another_column_count_is_refused_with_file_and_line(
        tmp_path: Path, row: str, columns: int) -> None:
    path = static_csv(tmp_path / "rec.csv", extra={7: row})
    code, err = analyze("allan", str(path))
    assert code == 2
    line = one_line(err)
    assert f"{path}:7: {columns:,} columns, but the header has 2" in line


def test_a_million_column_header_is_refused_in_a_short_line(tmp_path: Path) -> None:
    path = tmp_path / "wide.csv"
    path.write_text(",".join(f"c{i}" for i in range(1_000_000)) + "\n1,2\n", encoding="utf-8")
    code, err = analyze("allan", str(path))
    assert code == 2
    assert "header line is longer than 4,096 characters" in one_line(err)


@pytest.mark.parametrize("kind", ["/dev/zero", "huge"])
def test_a_device_or_a_huge_file_is_refused_before_reading(tmp_path: Path, kind: str) -> None:
    path = Path(kind)
    if kind == "huge":
        path = tmp_path / "huge.csv"
        with path.open("wb") as fh:
            fh.write(b"time_s,rate_dps\n")
            fh.truncate(MAX_CSV_BYTES + 1)  # sparse
    elif not path.exists():
        pytest.skip("no /dev/zero here")
    t0 = time.monotonic()
    code, err = analyze("allan", str(path))
    assert time.monotonic() - t0 < 5.0
    assert code == 2
    line = one_line(err)
    assert ("not a regular file" in line) if kind == "/dev/zero" else ("bytes, more than" in line)


def test_a_long_field_is_shown_cut(tmp_path: Path) -> None:
    path = static_csv(tmp_path / "rec.csv", extra={5: "0.03," + "x" * 100_000})
    code, err = analyze("allan", str(path))
    assert code == 2
    line = one_line(err)
    assert "column rate_dps" in line and "(100,000 chars)" in line


def test_the_replay_and_the_discrepancy_csv_refuse_a_wider_row(tmp_path: Path) -> None:
    from drivers.part_codes import ADIS16130
    from drivers.replay_source import RecordingError, load_recording
    from procedures.model.data import load_csv

    rec = tmp_path / "part.csv"
    rec.write_text("time_s,rate_dps,temp_c\n0,1,25\n0.01,1,25,99\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=r"part\.csv:3: 4 columns, but the header has 3"):
        load_recording(rec, ADIS16130)
    disc = tmp_path / "disc.csv"
    header = "time_s,gyro_dps,ref_rate_dps,ref_angle_deg,temp_c,supply_v"
    rows = [f"{i * 0.1:.1f},1,0,0,25,5" for i in range(20)]
    rows[4] += ",extra"
    disc.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match=r"disc\.csv:6: 7 columns, but the header has 6"):
        load_csv(disc)
