"""approvals.json is read with a bound, like record.json: a huge or damaged file is refused
in one line naming it, never loaded whole."""

from __future__ import annotations

from pathlib import Path

import pytest

from station.approvals import MAX_APPROVALS_BYTES, read_approvals
from station.errors import UserError
from station.manifest import APPROVALS_FILE


def test_a_huge_approvals_file_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / APPROVALS_FILE
    with path.open("wb") as fh:  # a sparse 1 GB file: reading it whole would take 1 GB
        fh.truncate(1024 * MAX_APPROVALS_BYTES)
    with pytest.raises(UserError, match="larger than 1024 kB") as caught:
        read_approvals(tmp_path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_approvals_within_the_bound_are_read(tmp_path: Path) -> None:
    (tmp_path / APPROVALS_FILE).write_text(
        '{"approvals": [{"by": "Q. Engineer"}, "not an entry"]}', encoding="utf-8"
    )
    assert read_approvals(tmp_path) == [{"by": "Q. Engineer"}]
    (tmp_path / APPROVALS_FILE).write_bytes(b"\xff\xfe")
    with pytest.raises(UserError, match="damaged"):
        read_approvals(tmp_path)
