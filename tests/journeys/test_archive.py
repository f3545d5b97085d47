"""Retention, as docs/records.md shows it: `station archive --older-than DAYS` packs finished,
sealed run folders into one RUN.tar.xz each, points the results database at them and removes
the folders; `station verify RUN.tar.xz` checks an archive as it checks a folder.

Two sealed runs (station key and database of their own): one finished 40 days ago, one 2
days ago. Each test archives a fresh copy of them. Interruptions are reproduced by the files
they leave behind (a cut-short archive, a partial temp file, a folder half removed)."""

from __future__ import annotations

import datetime as dt
import errno
import io
import os
import shutil
import subprocess
import sys
import tarfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import sqlalchemy as sa

from station import retention
from station.certify import finish_run_folder
from station.db.connect import dispose_all
from station.db.schema import outbox
from station.results_db import ResultsDB
from station.settings import LoadedSettings
from station.station_file import load_settings
from tests.reports.synth_run import Part, make_run
from tests.reports.test_signing import station, station_file

STATION_CMD = Path(sys.executable).parent / "station"
NOW = dt.datetime.now(dt.UTC)
Members = list[tuple[tarfile.TarInfo, bytes]]


@dataclass
class Line:
    settings: LoadedSettings
    runs: Path  # holds the two run folders
    old: Path  # finished 40 days ago
    young: Path  # finished 2 days ago
    db: ResultsDB

    @property
    def archive(self) -> Path:
        return self.runs / "archive" / f"{self.old.name}.tar.xz"

    def archive_cmd(self, *extra: str) -> tuple[int, str, str]:
        return station("archive", "--older-than", "30", "--db", str(self.db.path),
                       "--station", str(self.settings.source.path), *extra, str(self.runs))

    def verify(self, target: Path) -> tuple[int, str, str]:
        return station("verify", str(target), "--station", str(self.settings.source.path))


@pytest.fixture(scope="module")
def sealed(tmp_path_factory: pytest.TempPathFactory) -> tuple[LoadedSettings, Path]:
    settings = load_settings(station_file(tmp_path_factory.mktemp("station")))
    root = tmp_path_factory.mktemp("runs")
    for serial, age in (("SIM-OLD-1", 40), ("SIM-YOUNG-2", 2)):
        started = NOW - dt.timedelta(days=age, minutes=31)
        folder, _ = make_run(root, Part(serial=serial, started=started.replace(microsecond=0)))
        assert finish_run_folder(folder, settings, certificate=True) is not None
    return settings, root


@pytest.fixture
def line(sealed: tuple[LoadedSettings, Path], tmp_path: Path) -> Iterator[Line]:
    settings, root = sealed
    runs = Path(shutil.copytree(root, tmp_path / "runs"))
    old, young = (next(runs.glob(f"*{s}*")) for s in ("SIM-OLD-1", "SIM-YOUNG-2"))
    db = ResultsDB(tmp_path / "results.sqlite")
    db.add_run(old)
    db.add_run(young)
    yield Line(settings, runs, old, young, db)
    dispose_all()


def _members(archive: Path) -> Members:
    with tarfile.open(archive, "r:xz") as tar:
        return [(m, (tar.extractfile(m) or io.BytesIO()).read() if m.isfile() else b"")
                for m in tar]


def _rewrite(archive: Path, change: Callable[[Members], Members]) -> None:
    members = change(_members(archive))
    with tarfile.open(archive, "w:xz") as tar:
        for info, data in members:
            info.size = len(data) if info.isfile() else 0
            tar.addfile(info, io.BytesIO(data) if info.isfile() else None)


def test_the_documented_command_archives_old_runs_only(line: Line) -> None:
    """The journey: the installed command, then verify the archive, then the database."""
    done = subprocess.run([str(STATION_CMD), "archive", "--older-than", "30", "--db",
                           str(line.db.path), "--station", str(line.settings.source.path),
                           str(line.runs)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"archived {line.old} -> {line.archive}" in done.stdout
    assert "1 archived" in done.stdout and "1 younger than 30 days" in done.stdout
    assert not line.old.exists() and line.young.is_dir() and line.archive.is_file()
    code, out, _ = line.verify(line.archive)
    assert code == 0 and f"{line.archive}: intact" in out, out
    rows = {r.serial: r.folder for r in line.db.runs()}
    assert rows["SIM-OLD-1"] == f"{line.archive.resolve()}#{line.old.name}"
    assert rows["SIM-YOUNG-2"] == str(line.young.resolve())
    with line.db.engine.connect() as con:  # queued again for the line's central database
        versions = {r.run_id: r.version
                    for r in con.execute(sa.select(outbox.c.run_id, outbox.c.version))}
    assert [versions[r.run_id] for r in line.db.runs()] == [2, 1]
    names = [m.name for m, _ in _members(line.archive)]
    assert names[0] == line.old.name and names[-1] == f"{line.old.name}/raw.h5"
    assert f"{line.old.name}/manifest.json" in names


def test_the_age_is_the_records_finish_time_not_the_files_time(line: Line) -> None:
    """The old folder's files touched now, the young one's a year back: nothing changes."""
    for folder, when in ((line.old, NOW), (line.young, NOW - dt.timedelta(days=365))):
        for path in (folder, *folder.iterdir()):
            os.utime(path, (when.timestamp(), when.timestamp()))
    assert line.archive_cmd()[0] == 0
    assert not line.old.exists() and line.young.is_dir()


def test_a_running_run_is_never_archived(line: Line) -> None:
    (line.old / ".running").write_text('{"pid": 1}')
    code, out, _ = line.archive_cmd()
    assert code == 0 and "0 archived" in out and "1 running" in out, out
    assert line.old.is_dir() and not line.archive.exists()
    assert line.db.folder_of(line.db.runs(serial="SIM-OLD-1")[0].run_id) == str(
        line.old.resolve())


@pytest.mark.parametrize("tamper,named", [
    ("raw byte", "raw.h5"), ("member added", "notes.txt"), ("member twice", "record.json"),
])
def test_a_tampered_archive_is_altered(line: Line, tamper: str, named: str) -> None:
    assert line.archive_cmd()[0] == 0
    assert line.verify(line.archive)[0] == 0

    def change(members: Members) -> Members:
        run = members[0][0].name
        if tamper == "raw byte":
            info, data = next((i, d) for i, d in members if i.name.endswith("/raw.h5"))
            flipped = bytearray(data)
            flipped[len(flipped) // 2] ^= 0x01
            return [(i, bytes(flipped) if i is info else d) for i, d in members]
        if tamper == "member added":
            return [*members, (tarfile.TarInfo(f"{run}/notes.txt"), b"added")]
        record = next((i, d) for i, d in members if i.name.endswith("/record.json"))
        return [*members, record]

    _rewrite(line.archive, change)
    code, out, _ = line.verify(line.archive)
    assert code == 1, out
    assert f"{line.archive}: ALTERED: {named}" in out


def test_a_truncated_archive_is_altered_and_a_rerun_writes_it_again(line: Line) -> None:
    """Killed while writing, after the rename (or a disk that lost the end): the folder is
    kept until a rerun has written an archive that verifies."""
    assert line.archive_cmd()[0] == 0
    good = line.archive.read_bytes()
    shutil.copytree(line.runs / "archive", line.runs.parent / "keep")
    # put the state back: the folder as it was, the archive cut in half, the row on the folder
    with tarfile.open(line.runs.parent / "keep" / line.archive.name) as tar:
        tar.extractall(line.runs, filter="data")
    line.archive.write_bytes(good[: len(good) // 2])
    line.db.relocate(line.db.runs(serial="SIM-OLD-1")[0].run_id, str(line.old.resolve()))
    code, out, _ = line.verify(line.archive)
    assert code == 1 and "truncated or damaged" in out, out
    code, out, err = line.archive_cmd()
    assert code == 0, out + err
    assert not line.old.exists() and line.verify(line.archive)[0] == 0
    assert line.db.runs(serial="SIM-OLD-1")[0].folder.endswith(f".tar.xz#{line.old.name}")


def test_a_partial_file_left_by_a_killed_run_is_cleaned_up(line: Line) -> None:
    partial = line.runs / "archive" / f".{line.old.name}.partial.tar.xz"
    partial.parent.mkdir()
    partial.write_bytes(b"\xfd7zXZ\x00 cut short")
    assert line.archive_cmd()[0] == 0
    assert not partial.exists() and not line.old.exists()
    assert line.verify(line.archive)[0] == 0


def test_killed_before_the_folder_was_removed_a_rerun_completes(line: Line) -> None:
    """The archive written and renamed, the database and the folder not yet: the rerun
    keeps that archive (same file), points the row at it and removes the folder."""
    (line.runs / "archive").mkdir()
    from station.run_archive import write_archive

    write_archive(line.old, line.archive)
    before = line.archive.stat().st_ino
    assert line.archive_cmd()[0] == 0
    assert line.archive.stat().st_ino == before and not line.old.exists()
    assert line.db.runs(serial="SIM-OLD-1")[0].folder.endswith(f"#{line.old.name}")


def test_a_removal_cut_short_is_finished(line: Line) -> None:
    """Killed while removing: some files gone, record.json (removed last) still there."""
    assert line.archive_cmd()[0] == 0
    with tarfile.open(line.archive) as tar:
        tar.extractall(line.runs, filter="data")
    for name in ("certificate.pdf", "raw.h5", "manifest.json"):
        (line.old / name).unlink()
    assert line.archive_cmd()[0] == 0
    assert not line.old.exists() and line.verify(line.archive)[0] == 0


def test_an_altered_folder_is_kept_and_named(line: Line) -> None:
    with (line.old / "raw.h5").open("r+b") as fh:
        fh.seek(100)
        byte = fh.read(1)
        fh.seek(100)
        fh.write(bytes([byte[0] ^ 1]))
    code, _, err = line.archive_cmd()
    assert code == 1, err
    assert f"not archived: {line.old} failed verification" in err
    assert f"station verify {line.old}" in err
    assert line.old.is_dir() and not line.archive.exists()


def test_disk_full_leaves_the_archive_out_and_keeps_the_folder(
        line: Line, monkeypatch: pytest.MonkeyPatch) -> None:
    def full(folder: Path, target: Path) -> None:
        target.write_bytes(b"\xfd7zXZ\x00 half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(retention, "write_archive", full)
    code, _, err = line.archive_cmd()
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "No space left on device" in lines[0] and "archive left out" in lines[0]
    assert f"{line.old} kept" in lines[0] and "--out" in lines[0]
    assert line.old.is_dir() and sorted(p.name for p in (line.runs / "archive").iterdir()) == [
        ".archive.lock"]


def test_a_folder_that_cannot_be_removed_stops_and_a_rerun_completes(
        line: Line, monkeypatch: pytest.MonkeyPatch) -> None:
    def refused(folder: Path) -> None:
        raise PermissionError(13, "Permission denied", str(folder / "raw.h5"))

    monkeypatch.setattr(retention, "_remove", refused)
    code, _, err = line.archive_cmd()
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{line.old}/raw.h5: Permission denied; stopped, nothing lost" in err
    assert line.old.is_dir() and line.verify(line.archive)[0] == 0
    assert line.db.runs(serial="SIM-OLD-1")[0].folder.endswith(f"#{line.old.name}")
    monkeypatch.undo()
    assert line.archive_cmd()[0] == 0 and not line.old.exists()


@pytest.mark.parametrize("days", ["abc", "0", "-3", "nan", "inf"])
def test_days_not_a_positive_number_is_one_line(line: Line, days: str) -> None:
    code, out, err = station("archive", "--older-than", days, str(line.runs))
    assert code == 2 and out == ""
    assert err.strip() == (f"station archive: error: --older-than {days!r}: give a positive "
                           "number of days, e.g. --older-than 90")


def test_no_such_folder_is_one_line(tmp_path: Path) -> None:
    code, _, err = station("archive", "--older-than", "30", str(tmp_path / "nowhere"))
    assert code == 2
    assert err.strip() == (f"station archive: error: {tmp_path / 'nowhere'}: no such folder; "
                           "give the folder holding the run folders (station.yaml's "
                           "output_folder)")


def test_a_file_that_is_no_archive_is_not_a_run(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "empty.tar.xz").write_bytes(b"")
    assert station("verify", str(tmp_path / "notes.txt"))[0] == 2
    code, out, _ = station("verify", str(tmp_path / "empty.tar.xz"))
    assert code == 1 and "truncated or damaged" in out


def test_station_help_lists_archive() -> None:
    shown = subprocess.run([str(STATION_CMD), "--help"], capture_output=True, text=True,
                           timeout=60)
    assert shown.returncode == 0
    assert "archive      pack finished run folders older than DAYS into archives" in shown.stdout
    usage = subprocess.run([str(STATION_CMD), "archive", "--help"], capture_output=True,
                           text=True, timeout=60).stdout
    assert all(o in usage for o in ("--older-than DAYS", "--out FOLDER", "RUNS_DIR"))
