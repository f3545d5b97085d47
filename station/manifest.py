"""Tamper evidence for a run folder: `manifest.json`, the signed hashes of its files.

    {"format": "gyrocal-manifest/1",
     "body": {"run_id": ..., "sealed_utc": ..., "origin": "run" | "report" | "approval",
              "files": {"record.json": {"sha256": ..., "bytes": ...}, "raw.h5": ...,
                        "certificate.pdf": ..., "approvals.json": ... or null when absent},
              "signer": {"fingerprint_sha256": ..., "subject": ..., "certificate_pem": ...}},
     "signature": {"algorithm": "rsa-pkcs1v15-sha256", "value": base64}}

The signature covers the body serialised canonically (keys sorted, no spaces, UTF-8).
`verify_folder` recomputes every hash, checks the signature with the certificate in the
body and, when given the station's trusted certificate fingerprints, that the signer is one
of them (a manifest re-signed with another key is as good as none).
"""

from __future__ import annotations

import base64
import datetime as dt
import hashlib
import json
import os
import re
import stat
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import padding, rsa

from procedures.runtime.record import CERTIFICATE_FILE, RAW_DATA_FILE, RECORD_FILE, new_file_mode
from station.signing_keys import StationIdentity, certificate_fingerprint

MANIFEST_FILE = "manifest.json"
APPROVALS_FILE = "approvals.json"
FORMAT = "gyrocal-manifest/1"
ALGORITHM = "rsa-pkcs1v15-sha256"
SEALED_FILES = (RECORD_FILE, RAW_DATA_FILE, CERTIFICATE_FILE, APPROVALS_FILE)
# files the station itself adds to a sealed folder without sealing them (docs/records.md):
# the manifest, `station report --unverified`'s certificate, the lock of a run in progress
UNVERIFIED_FILE = "certificate-UNVERIFIED.pdf"
UNSEALED_FILES = (MANIFEST_FILE, UNVERIFIED_FILE, ".running")
# ... and the temp file of an atomic write (tempfile.mkstemp's names), left by a crash
_TEMP_FILE = re.compile(
    r"\.(record|manifest|certificate|certificate-UNVERIFIED|approvals)-[a-z0-9_]{8}\.(json|pdf)"
)
# a manifest is a few kB (its signer certificate most of it); read none beyond this
MAX_MANIFEST_BYTES = 1 << 20
_CHUNK = 1 << 20


class Status(IntEnum):
    """`station verify`'s exit codes (pinned)."""

    INTACT = 0
    ALTERED = 1
    NOT_A_RUN_FOLDER = 2


@dataclass
class Verification:
    status: Status
    problems: list[str] = field(default_factory=list)
    altered_files: list[str] = field(default_factory=list)
    signer_fingerprint: str = ""
    origin: str = ""  # what sealed the folder last
    first_origin: str = ""  # what sealed it first (`run`: the evidence starts at the run)

    @property
    def intact(self) -> bool:
        return self.status is Status.INTACT


def file_digest(path: Path) -> dict[str, Any]:
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return {"sha256": h.hexdigest(), "bytes": size}


def canonical(body: dict[str, Any]) -> bytes:
    return json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


def is_run_folder(folder: Path) -> bool:
    return folder.is_dir() and any((folder / n).is_file() for n in (RECORD_FILE, RAW_DATA_FILE))


def _first_sealed(folder: Path, identity: StationIdentity) -> dict[str, Any] | None:
    """The first sealing ({origin, sealed_utc}) the folder's present manifest vouches for:
    carried from one manifest to the next, so a folder sealed at the run and sealed again by
    `station report` or an approval still says its evidence starts at the run. None when
    there is no manifest this station signed (the new one is then the first)."""
    doc, _ = _read_manifest(folder)
    if doc is None or _check_signature(doc, {identity.fingerprint})[1]:
        return None
    body = doc["body"]
    first = body.get("first_sealed")
    if isinstance(first, dict) and isinstance(first.get("origin"), str):
        return {"origin": first["origin"], "sealed_utc": str(first.get("sealed_utc", ""))}
    return {"origin": str(body.get("origin", "")), "sealed_utc": str(body.get("sealed_utc", ""))}


def build_body(folder: Path, identity: StationIdentity, origin: str) -> dict[str, Any]:
    files = {name: (file_digest(folder / name) if (folder / name).is_file() else None)
             for name in SEALED_FILES}
    now = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    return {
        "run_id": folder.name,
        "sealed_utc": now,
        "origin": origin,
        "first_sealed": _first_sealed(folder, identity) or {"origin": origin, "sealed_utc": now},
        "files": files,
        "signer": {"fingerprint_sha256": identity.fingerprint, "subject": identity.subject,
                   "certificate_pem": identity.certificate_pem()},
    }


def seal(folder: Path, identity: StationIdentity, origin: str) -> Path:
    """Write (or replace) the folder's signed manifest; returns its path."""
    body = build_body(folder, identity, origin)
    doc = {"format": FORMAT, "body": body,
           "signature": {"algorithm": ALGORITHM,
                         "value": base64.b64encode(identity.sign(canonical(body))).decode()}}
    target = folder / MANIFEST_FILE
    fd, tmp = tempfile.mkstemp(prefix=".manifest-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            os.fchmod(fh.fileno(), new_file_mode())
            json.dump(doc, fh, indent=2, sort_keys=True)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target


def _read_manifest(folder: Path) -> tuple[dict[str, Any] | None, str]:
    path = folder / MANIFEST_FILE
    if path.is_symlink():
        return None, f"{MANIFEST_FILE} is a symbolic link (the station writes a plain file)"
    if not path.is_file():
        return None, (f"{MANIFEST_FILE} is missing: the folder was never sealed (a run from "
                      "before signing) or its manifest was removed")
    try:
        with path.open("rb") as fh:
            data = fh.read(MAX_MANIFEST_BYTES + 1)
    except OSError as exc:
        return None, f"{MANIFEST_FILE} cannot be read ({' '.join(str(exc).split())[:200]})"
    return parse_manifest(data)


def parse_manifest(data: bytes) -> tuple[dict[str, Any] | None, str]:
    """A manifest's document from its bytes (at most MAX_MANIFEST_BYTES + 1 of them), or
    None and what is wrong with it."""
    if len(data) > MAX_MANIFEST_BYTES:
        return None, (f"{MANIFEST_FILE} is larger than {MAX_MANIFEST_BYTES:,} bytes "
                      "(a manifest is a few kB)")
    try:
        doc = json.loads(data.decode("utf-8"))
        if doc.get("format") != FORMAT or not isinstance(doc.get("body"), dict):
            return None, f"{MANIFEST_FILE} is not a {FORMAT} manifest"
        return doc, ""
    except (ValueError, AttributeError) as exc:
        return None, f"{MANIFEST_FILE} cannot be read ({' '.join(str(exc).split())[:200]})"


def _check_signature(doc: dict[str, Any], trusted: set[str] | None) -> tuple[str, str]:
    """(signer fingerprint, problem or '')."""
    body = doc["body"]
    try:
        cert = x509.load_pem_x509_certificate(body["signer"]["certificate_pem"].encode())
        value = base64.b64decode(doc["signature"]["value"], validate=True)
        if doc["signature"]["algorithm"] != ALGORITHM:
            return "", f"{MANIFEST_FILE}: unknown signature algorithm"
    except (KeyError, TypeError, ValueError) as exc:
        return "", f"{MANIFEST_FILE}: signer or signature unreadable ({exc})"
    fingerprint = certificate_fingerprint(cert)
    public = cert.public_key()
    if not isinstance(public, rsa.RSAPublicKey):
        return fingerprint, f"{MANIFEST_FILE}: signer certificate is not RSA"
    try:
        public.verify(value, canonical(body), padding.PKCS1v15(), hashes.SHA256())
    except InvalidSignature:
        return fingerprint, f"{MANIFEST_FILE}: signature does not match its content (altered)"
    if trusted is not None and fingerprint not in trusted:
        return fingerprint, (f"{MANIFEST_FILE}: signed by certificate {fingerprint[:16]}..., "
                             "which is not this station's (re-signed elsewhere)")
    return fingerprint, ""


def check_entries(files: dict[str, Any], kinds: dict[str, str],
                  same: Callable[[str, Any], bool]) -> dict[str, str]:
    """The entries that differ from the manifest's `files`, each with what happened: changed,
    removed, a symbolic link, or added after sealing (any name but the sealed files and the
    ones the station adds later, UNSEALED_FILES). `kinds`: each entry present, by name, as
    "file", "link" or "other"; `same(name, expected)`: that file matches its manifest entry.
    A folder and an archive (station/run_archive.py) are judged by this one rule."""
    altered: dict[str, str] = {}
    for name in SEALED_FILES:
        expected, kind = files.get(name), kinds.get(name)
        if kind == "link":  # even to an identical copy: the folder must hold its data
            altered[name] = "replaced by a symbolic link"
        elif expected is None:
            if kind is not None:
                altered[name] = "added after sealing"
        elif kind is None:
            altered[name] = "removed"
        elif not same(name, expected):
            altered[name] = "changed"
    for name in sorted(kinds):
        if name in SEALED_FILES or _TEMP_FILE.fullmatch(name):
            continue
        if name in UNSEALED_FILES and kinds[name] != "link":
            continue
        altered[name] = "added after sealing"
    return altered


def _kind(path: Path) -> str | None:
    try:
        mode = path.lstat().st_mode
    except OSError:
        return None
    return "link" if stat.S_ISLNK(mode) else "file" if stat.S_ISREG(mode) else "other"


def folder_changes(folder: Path, files: dict[str, Any]) -> dict[str, str]:
    """check_entries over a folder's entries."""
    try:
        names = os.listdir(folder)
    except OSError as exc:
        names, unreadable = [], f"unreadable ({exc.strerror or exc})"
    else:
        unreadable = ""
    kinds = {name: kind for name in {*SEALED_FILES, *names}
             if (kind := _kind(folder / name)) is not None}
    altered = check_entries(files, kinds, lambda name, expected: _same(folder / name, expected))
    return {**altered, ".": unreadable} if unreadable else altered


def _same(path: Path, expected: Any) -> bool:
    """A regular file of the manifest's size and hash (the size first: a file grown to any
    length is not read through)."""
    try:
        st = path.stat()
    except OSError:
        return False
    if not stat.S_ISREG(st.st_mode):
        return False
    if isinstance(expected, dict) and expected.get("bytes") != st.st_size:
        return False
    return file_digest(path) == expected


def verify_folder(folder: Path, trusted: set[str] | None = None) -> Verification:
    """Check a run folder against its manifest. `trusted`: the signer fingerprints to accept
    (None: any signer whose signature is valid)."""
    folder = Path(folder)
    if not is_run_folder(folder):
        return Verification(Status.NOT_A_RUN_FOLDER, [
            f"{folder} is not a run folder (neither {RECORD_FILE} nor {RAW_DATA_FILE} in it)"])
    doc, problem = _read_manifest(folder)
    return judge(doc, problem, trusted, lambda files: folder_changes(folder, files))


def judge(doc: dict[str, Any] | None, problem: str, trusted: set[str] | None,
          changes: Callable[[dict[str, Any]], dict[str, str]]) -> Verification:
    """The verdict on a run's manifest (`doc`, or None and the `problem` reading it) and its
    files: `changes(manifest files)` says which differ (check_entries)."""
    if doc is None:
        return Verification(Status.ALTERED, [problem], [MANIFEST_FILE])
    fingerprint, problem = _check_signature(doc, trusted)
    origin = str(doc["body"].get("origin", ""))
    first = doc["body"].get("first_sealed")
    result = Verification(Status.INTACT, signer_fingerprint=fingerprint, origin=origin,
                          first_origin=str(first.get("origin", origin))
                          if isinstance(first, dict) else origin)
    if problem:
        result.status = Status.ALTERED
        result.problems.append(problem)
        result.altered_files.append(MANIFEST_FILE)
        return result
    files = doc["body"].get("files")
    if not isinstance(files, dict):
        return Verification(Status.ALTERED, [f"{MANIFEST_FILE}: no file list"], [MANIFEST_FILE])
    for name, state in changes(files).items():
        result.status = Status.ALTERED
        result.altered_files.append(name)
        result.problems.append(f"{name} was {state} since the folder was sealed")
    return result
