"""A run folder packed into one compressed archive, read and verified without unpacking.

    RUN.tar.xz   one archive per run folder (written by `station archive`, station/retention.py)
        RUN/                      the folder itself
        RUN/manifest.json         then the small files: record.json, certificate.pdf, ...
        RUN/raw.h5                the raw data last

The archive holds the folder's files as they were, so the folder's own manifest verifies it by
the same rule as the folder (station/manifest.py's check_entries): every file's hash, the
manifest's signature, nothing added. Members are small files first and raw.h5 last, so a
certificate is read without decompressing the raw data. Damage is found: xz checks its blocks,
and a truncated archive cannot be read to its end.

The results database points at an archived run with the text `ARCHIVE#RUN`, e.g.
`/data/runs/archive/EOL-A_0042.tar.xz#EOL-A_0042` (archive_ref, split_ref).
"""

from __future__ import annotations

import hashlib
import lzma
import os
import tarfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from procedures.runtime.record import RAW_DATA_FILE, RECORD_FILE
from station.manifest import (
    MANIFEST_FILE,
    MAX_MANIFEST_BYTES,
    Status,
    Verification,
    check_entries,
    judge,
    parse_manifest,
)

SUFFIX = ".tar.xz"
READABLE_SUFFIXES = (".tar.xz", ".tar.gz", ".tgz", ".tar")
_CHUNK = 1 << 20
_DAMAGE = (tarfile.TarError, EOFError, lzma.LZMAError, zlib.error, OSError)


def is_archive_name(path: Path | str) -> bool:
    return str(path).lower().endswith(READABLE_SUFFIXES)


def archive_ref(archive: Path, run: str) -> str:
    """The results database's `folder` for a run archived in `archive`."""
    return f"{archive}#{run}"


def split_ref(folder: str) -> tuple[Path, str] | None:
    """(archive, run folder name) when `folder` is an archive_ref, else None."""
    head, sep, run = folder.rpartition("#")
    if not sep or not run or "/" in run or not is_archive_name(head):
        return None
    return Path(head), run


def _order(name: str) -> tuple[int, str]:
    return (0 if name == MANIFEST_FILE else 2 if name == RAW_DATA_FILE else 1, name)


def write_archive(folder: Path, target: Path) -> None:
    """Pack the folder's files into a new file `target` (xz), written through to the disk.
    Raises ValueError for an entry that is not a plain file, OSError when writing fails."""
    names = sorted(os.listdir(folder), key=_order)
    for name in names:
        if not (folder / name).is_file() or (folder / name).is_symlink():
            raise ValueError(f"{folder / name} is not a plain file (a run folder holds files)")
    with open(target, "xb") as fh:
        with tarfile.open(fileobj=fh, mode="w:xz", format=tarfile.PAX_FORMAT) as tar:
            tar.add(folder, arcname=folder.name, recursive=False)
            for name in names:
                tar.add(folder / name, arcname=f"{folder.name}/{name}", recursive=False)
        fh.flush()
        os.fsync(fh.fileno())


@dataclass
class Scan:
    """What an archive holds, read to its end: each entry's kind and each file's digest
    (by name inside the run folder; an entry outside it by its full name)."""

    run: str = ""
    kinds: dict[str, str] = field(default_factory=dict)
    digests: dict[str, dict[str, object]] = field(default_factory=dict)
    manifest: bytes = b""
    duplicates: list[str] = field(default_factory=list)


def _digest(tar: tarfile.TarFile, member: tarfile.TarInfo, keep: bool) -> tuple[dict[str, object],
                                                                                  bytes]:
    h, size, kept = hashlib.sha256(), 0, bytearray()
    fh = tar.extractfile(member)
    assert fh is not None  # a regular file's member
    while chunk := fh.read(_CHUNK):
        h.update(chunk)
        size += len(chunk)
        if keep and len(kept) <= MAX_MANIFEST_BYTES:
            kept += chunk[:MAX_MANIFEST_BYTES + 1 - len(kept)]
    return {"sha256": h.hexdigest(), "bytes": size}, bytes(kept)


def _entry_name(scan: Scan, member: tarfile.TarInfo) -> str | None:
    """The member's name inside the run folder; None for the folder itself."""
    top, _, rest = member.name.partition("/")
    if not scan.run:
        scan.run = top
    if top == scan.run and not rest and member.isdir():
        return None
    return rest if top == scan.run and rest and "/" not in rest else member.name


def scan_archive(path: Path) -> Scan:
    """Read the whole archive. Raises one of _DAMAGE when it cannot be read to its end."""
    scan = Scan()
    with tarfile.open(path, "r:*") as tar:
        for member in tar:
            name = _entry_name(scan, member)
            if name is None:
                continue
            if name in scan.kinds:
                scan.duplicates.append(name)
            if member.isfile():
                scan.kinds[name] = "file"
                scan.digests[name], kept = _digest(tar, member, keep=name == MANIFEST_FILE)
                if name == MANIFEST_FILE:
                    scan.manifest = kept
            else:
                scan.kinds[name] = "link" if member.issym() or member.islnk() else "other"
    return scan


def _manifest_of(scan: Scan) -> tuple[dict[str, object] | None, str]:
    kind = scan.kinds.get(MANIFEST_FILE)
    if kind is None:
        return None, (f"{MANIFEST_FILE} is missing: the folder was never sealed (a run from "
                      "before signing) or its manifest was removed")
    if kind != "file":
        return None, f"{MANIFEST_FILE} is not a plain file in the archive"
    return parse_manifest(scan.manifest)


def verify_archive(path: Path, trusted: set[str] | None = None) -> Verification:
    """Check a run archive as verify_folder checks a folder (same exit statuses): altered
    also when it cannot be read to its end, or a name appears twice in it."""
    return examine(path, trusted)[0]


def examine(path: Path, trusted: set[str] | None = None) -> tuple[Verification, bytes]:
    """verify_archive's verdict and the archived manifest's bytes (b"" without one)."""
    path = Path(path)
    if not path.is_file() or not is_archive_name(path):
        return Verification(Status.NOT_A_RUN_FOLDER, [
            f"{path} is neither a run folder nor a run archive (RUN{SUFFIX})"]), b""
    try:
        scan = scan_archive(path)
    except _DAMAGE as exc:
        return Verification(Status.ALTERED, [
            f"{path.name} cannot be read to its end ({' '.join(str(exc).split())[:200]}): "
            "a truncated or damaged archive"], [path.name]), b""
    if RECORD_FILE not in scan.kinds and RAW_DATA_FILE not in scan.kinds:
        return Verification(Status.NOT_A_RUN_FOLDER, [
            f"{path} is not a run archive (neither {RECORD_FILE} nor {RAW_DATA_FILE} in it)"]), b""
    doc, problem = _manifest_of(scan)
    result = judge(doc, problem, trusted, lambda files: check_entries(
        files, scan.kinds, lambda name, expected: scan.digests.get(name) == expected))
    for name in scan.duplicates:
        result.status = Status.ALTERED
        result.altered_files.append(name)
        result.problems.append(f"{name} appears twice in the archive (added after sealing)")
    return result, scan.manifest


def read_member(archive: Path, run: str, name: str, limit: int) -> bytes | None:
    """One file of an archived run folder (its first copy), or None when the archive does not
    hold it, cannot be read or the file is larger than `limit` bytes."""
    wanted = f"{run}/{name}"
    try:
        with tarfile.open(archive, "r:*") as tar:
            for member in tar:
                if member.name == wanted and member.isfile() and member.size <= limit:
                    fh = tar.extractfile(member)
                    return fh.read() if fh is not None else None
    except _DAMAGE:
        return None
    return None
