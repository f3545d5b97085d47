"""Reading a user's CSV file: every way it can fail becomes one clear UserError."""

from __future__ import annotations

import csv
from pathlib import Path

from station.errors import UserError


def read_csv_rows(path: Path, expected_header: str) -> list[list[str]]:
    """The non-blank rows of a CSV file, header first; UserError naming the problem otherwise."""
    reader = None
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            rows = list(reader)
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder; give a CSV file") from None
    except UnicodeDecodeError as exc:
        raise UserError(
            f"{path}: not UTF-8 text (byte {exc.start}); save it as 'CSV UTF-8'"
        ) from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except csv.Error as exc:
        line = f": line {reader.line_num}" if reader is not None else ""
        raise UserError(
            f"{path}{line}: not a readable CSV ({exc}); a record has short numeric fields"
        ) from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise UserError(f"{path}: the file is empty; expected a header row {expected_header}")
    return rows
