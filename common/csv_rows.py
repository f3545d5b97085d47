"""Reading a CSV file the station did not write, with bounds (docs/input-bounds.md).

Before any row is read: the path must be a regular file (not a device such as /dev/zero or a
pipe, which never end) of at most MAX_CSV_BYTES, and its header line at most MAX_HEADER_CHARS
characters. Each row is then read as a stream and must have as many columns as the header
(refused with file:line). A field longer than csv's field limit (131,072 characters) is
refused by the csv module itself. Every message is one line of bounded length.
"""

from __future__ import annotations

import csv
import os
import stat
from collections.abc import Iterator
from pathlib import Path

MAX_CSV_BYTES = 256 * 1024 * 1024  # 10 h at 100 Hz of a dozen columns is ~150 MB
MAX_HEADER_CHARS = 4096
_SHOWN_CHARS = 60


class CsvInputError(ValueError):
    """The CSV file cannot be used; the message is one line naming the file (and line)."""


def shown(text: str, limit: int = _SHOWN_CHARS) -> str:
    """`text` quoted for a message, cut to `limit` characters."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"... ({len(text):,} chars)"


def check_csv_file(path: Path) -> None:
    """A regular file within MAX_CSV_BYTES; CsvInputError otherwise."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise CsvInputError(f"{path}: no such file") from None
    except OSError as exc:
        raise CsvInputError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise CsvInputError(f"{path}: is a folder; give a CSV file")
    if not stat.S_ISREG(st.st_mode):
        raise CsvInputError(f"{path}: not a regular file (a device or a pipe); give a CSV file")
    if st.st_size > MAX_CSV_BYTES:
        raise CsvInputError(
            f"{path}: {st.st_size:,} bytes, more than the {MAX_CSV_BYTES:,} a record may have; "
            "split the record"
        )


def csv_rows(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, cells) of every non-blank row, header first; every row has the
    header's column count. Raises CsvInputError (one line, file:line) on any problem."""
    check_csv_file(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            head = fh.readline(MAX_HEADER_CHARS + 1)
            while head and not head.strip():  # blank lines before the header
                head = fh.readline(MAX_HEADER_CHARS + 1)
            if len(head) > MAX_HEADER_CHARS:
                raise CsvInputError(
                    f"{path}: the header line is longer than {MAX_HEADER_CHARS:,} characters; "
                    "a record's header names a few columns"
                )
            fh.seek(0)
            reader = csv.reader(fh)
            width = 0
            try:
                for row in reader:
                    if not row or not any(c.strip() for c in row):
                        continue
                    if not width:
                        width = len(row)
                    elif len(row) != width:
                        raise CsvInputError(
                            f"{path}:{reader.line_num}: {len(row):,} columns, but the header "
                            f"has {width}; every row needs one value per header column"
                        )
                    yield reader.line_num, row
            except csv.Error as exc:
                raise CsvInputError(
                    f"{path}:{reader.line_num}: not a readable CSV "
                    f"({' '.join(str(exc).split())[:120]}); a record has short numeric fields"
                ) from None
    except UnicodeDecodeError as exc:
        raise CsvInputError(
            f"{path}: not UTF-8 text (byte {exc.start}); save it as 'CSV UTF-8'"
        ) from None
    except IsADirectoryError:
        raise CsvInputError(f"{path}: is a folder; give a CSV file") from None
    except OSError as exc:
        raise CsvInputError(f"{path}: cannot read it ({exc.strerror or exc})") from None
