"""Reading a user's CSV file: every way it can fail becomes one clear UserError.

The bounds (a regular file of limited size, the header line's length, one value per header
column in every row) are common.csv_rows'; docs/input-bounds.md lists them."""

from __future__ import annotations

from pathlib import Path

from common.csv_rows import CsvInputError, csv_rows
from station.errors import UserError


def read_csv_rows(path: Path, expected_header: str) -> list[list[str]]:
    """The non-blank rows of a CSV file, header first; UserError naming the problem otherwise."""
    try:
        rows = [row for _, row in csv_rows(path)]
    except CsvInputError as exc:
        raise UserError(str(exc)) from None
    if not rows:
        raise UserError(f"{path}: the file is empty; expected a header row {expected_header}")
    return rows
