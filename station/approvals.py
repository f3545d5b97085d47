"""A quality engineer's approval of a run: recorded, shown on the certificate, signed, sealed.

`approve(folder, settings, by=..., role="quality", remark=...)` refuses a folder that fails
verification (and a FAIL run approved without a remark), appends {by, role, time_utc,
remark, certificate_sha256 (of the PDF approved)} to `approvals.json`, issues the certificate
again with the approval in its "Reviewed by (quality)" box (station/certify.py: rendered
from the record and the approvals, the station's signature, then one PAdES signature per
approval, field Approval-N, the approver's name and the time in its reason), and writes a new
manifest that covers approvals.json. The signatures are made with the station's key on the
approver's behalf: the station's sign-in (station/ui/auth.py) is what vouches for who
approved.

Why re-render rather than only append a visible signature to the signed PDF: the approval
then is part of the page content (every viewer, a print and pdftotext show it), any number
of approvals fit the box, and `station approve` and `station report` produce the same
document from the same sealed files. The cost: the station's signature is made again at the
approval (its time changes); the certificate approved is identified by its SHA-256 in the
approval's entry.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

from procedures.runtime.record import CERTIFICATE_FILE, Verdict, read_record
from station.certify import signed_certificate, station_identity, trusted_fingerprints
from station.errors import UserError
from station.manifest import APPROVALS_FILE, file_digest, seal, verify_folder
from station.settings import LoadedSettings

MAX_NAME_CHARS = 120
MAX_REMARK_CHARS = 500
MAX_APPROVALS_BYTES = 1024 * 1024  # an approval is under 1 kB; read no more than this


def read_approvals(folder: Path) -> list[dict[str, Any]]:
    path = Path(folder) / APPROVALS_FILE
    if not path.is_file():
        return []
    try:
        with path.open("rb") as fh:  # bounded: a few approvals are a few kB
            raw = fh.read(MAX_APPROVALS_BYTES + 1)
        if len(raw) > MAX_APPROVALS_BYTES:
            raise ValueError(f"larger than {MAX_APPROVALS_BYTES // 1024} kB, not a file the "
                             "station wrote")
        entries = json.loads(raw.decode("utf-8")).get("approvals", [])
    except (OSError, ValueError, AttributeError) as exc:
        raise UserError(f"{path} cannot be read ({exc}); the run folder is damaged") from None
    return [e for e in entries if isinstance(e, dict)]


def _write_approvals(folder: Path, entries: list[dict[str, Any]]) -> None:
    from reports.pdfdoc import write_atomic  # reportlab (PDF): loaded only when a report is drawn

    text = json.dumps({"format": "gyrocal-approvals/1", "approvals": entries}, indent=2)
    write_atomic(folder / APPROVALS_FILE, (text + "\n").encode())


def approve(folder: Path, settings: LoadedSettings, *, by: str, role: str,
            remark: str = "") -> dict[str, Any]:
    """Record, show and sign an approval; returns the new entry. UserError when the folder
    is altered, has no certificate, the name is empty, or a run that did not PASS (FAIL,
    ERROR, ABORTED) has no remark."""
    # reportlab (PDF): loaded only when a report is drawn
    from reports.certificate import certificate_bytes
    from reports.pdfdoc import write_atomic

    folder = Path(folder)
    name, remark = by.strip(), remark.strip()
    if not name or len(name) > MAX_NAME_CHARS:
        raise UserError(f"approver name must be 1-{MAX_NAME_CHARS} characters")
    if len(remark) > MAX_REMARK_CHARS or not remark.isprintable():
        raise UserError(f"--remark must be at most {MAX_REMARK_CHARS} printable characters")
    result = verify_folder(folder, trusted_fingerprints(settings))
    if not result.intact:
        raise UserError(f"{folder} cannot be approved: " + "; ".join(result.problems))
    cert = folder / CERTIFICATE_FILE
    if not cert.is_file():
        raise UserError(f"{folder} has no certificate to approve; render it with "
                        "`station report RUN_FOLDER` first")
    try:
        record = read_record(folder)
    except ValueError as exc:
        raise UserError(f"{folder} cannot be approved: {exc}") from None
    if record.verdict is not Verdict.PASS and not remark:
        raise UserError(f"{folder} is a{'n' if record.verdict.value[0] in 'AE' else ''} "
                        f"{record.verdict.value} run: approving it needs a remark saying why "
                        "(--remark TEXT)")
    entries = read_approvals(folder)
    entry = {"by": name, "role": role,
             "time_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
             "certificate_sha256": file_digest(cert)["sha256"]}
    if remark:
        entry["remark"] = remark
    approvals = [*entries, entry]
    identity = station_identity(settings)
    pdf = signed_certificate(certificate_bytes(folder, approvals=approvals), identity,
                             settings.settings.station.id, record.certificate_number, approvals)
    write_atomic(cert, pdf)
    _write_approvals(folder, approvals)
    seal(folder, identity, "approval")
    return entry
