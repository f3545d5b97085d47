"""`station verify` against a folder altered around its files (a sealed file made a symbolic
link, a file added after sealing) and against inputs without bound (a huge manifest, a listed
file grown huge, `--trust /dev/zero`): altered (exit 1) naming the file, or refused in one line
(exit 2), each at once."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest

from station.manifest import MANIFEST_FILE
from station.settings import LoadedSettings
from tests.reports.test_signing import _issued, issued, settings, station, verify

__all__ = ["_issued", "issued", "settings"]  # the fixtures, shared with test_signing


@pytest.mark.parametrize("name", ["raw.h5", "record.json", "certificate.pdf"])
def test_a_sealed_file_made_a_symlink_to_an_identical_copy_is_altered(
        issued: Path, settings: LoadedSettings, tmp_path: Path, name: str) -> None:
    copy = tmp_path / f"outside-{name}"
    shutil.copy(issued / name, copy)
    (issued / name).unlink()
    (issued / name).symlink_to(copy)
    code, out, _ = verify(issued, settings)
    assert code == 1, out
    assert f"ALTERED: {name}" in out and f"{name} was replaced by a symbolic link" in out


@pytest.mark.parametrize("name", ["notes.txt", "raw-fixed.h5", ".hidden", "sub"])
def test_a_file_added_after_sealing_is_altered_naming_it(
        issued: Path, settings: LoadedSettings, name: str) -> None:
    if name == "sub":
        (issued / name).mkdir()
    else:
        (issued / name).write_bytes(b"added")
    code, out, _ = verify(issued, settings)
    assert code == 1, out
    assert f"ALTERED: {name}" in out and f"{name} was added after sealing" in out


def test_the_files_the_station_adds_later_leave_the_folder_intact(
        issued: Path, settings: LoadedSettings) -> None:
    (issued / "certificate-UNVERIFIED.pdf").write_bytes(b"%PDF")  # station report --unverified
    (issued / ".running").write_text("{}")  # a run's lock that could not be removed
    (issued / ".record-abc123_x.json").write_text("{}")  # an atomic write a crash cut short
    code, out, _ = verify(issued, settings)
    assert code == 0, out
    (issued / ".running").unlink()
    (issued / ".running").symlink_to(issued / "record.json")  # not as a link, though
    assert verify(issued, settings)[0] == 1


def test_a_two_gigabyte_manifest_is_refused_at_once(
        issued: Path, settings: LoadedSettings) -> None:
    manifest = issued / MANIFEST_FILE
    with manifest.open("r+b") as fh:
        fh.truncate(2 * 1024**3)  # sparse: costs no disk
    t0 = time.monotonic()
    code, out, _ = verify(issued, settings)
    assert time.monotonic() - t0 < 5.0
    assert code == 1 and f"{MANIFEST_FILE} is larger than" in out


def test_a_listed_file_grown_huge_is_altered_without_reading_it(
        issued: Path, settings: LoadedSettings) -> None:
    with (issued / "raw.h5").open("r+b") as fh:
        fh.truncate(50 * 1024**3)  # sparse 50 GB: hashing it would take minutes
    t0 = time.monotonic()
    code, out, _ = verify(issued, settings)
    assert time.monotonic() - t0 < 5.0
    assert code == 1 and "raw.h5 was changed" in out


@pytest.mark.parametrize("trust", ["/dev/zero", "big"])
def test_trust_reads_a_bounded_certificate(
        issued: Path, tmp_path: Path, trust: str) -> None:
    if trust == "big":
        trust = str(tmp_path / "big.pem")
        with open(trust, "wb") as fh:
            fh.truncate(2 * 1024**3)
    if not os.path.exists(trust):
        pytest.skip(f"{trust} does not exist here")
    t0 = time.monotonic()
    code, out, err = station("verify", str(issued), "--trust", trust)
    assert time.monotonic() - t0 < 5.0
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"trusted certificate {trust} is larger than 64 kB" in lines[0]
