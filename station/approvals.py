"""A quality engineer's approval of a run: recorded, signed into the PDF, sealed.

`approve(folder, settings, by=..., role="quality")` refuses a folder that fails
verification, appends {by, role, time_utc, certificate_sha256 (of the PDF approved)} to
`approvals.json`, adds a PAdES signature (field Approval-N, the approver's name and the time
in its reason) as an incremental update of certificate.pdf, and writes a new manifest that
covers approvals.json. The signature is made with the station's key on the approver's
behalf: the station's sign-in (station/ui/auth.py) is what vouches for who approved.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

from procedures.record import CERTIFICATE_FILE
from station.certify import approval_reason, station_identity, trusted_fingerprints
from station.errors import UserError
from station.manifest import APPROVALS_FILE, file_digest, seal, verify_folder
from station.pdf_signing import sign_pdf_bytes
from station.settings import LoadedSettings

MAX_NAME_CHARS = 120


def read_approvals(folder: Path) -> list[dict[str, Any]]:
    path = Path(folder) / APPROVALS_FILE
    if not path.is_file():
        return []
    try:
        entries = json.loads(path.read_text(encoding="utf-8")).get("approvals", [])
    except (OSError, ValueError, AttributeError) as exc:
        raise UserError(f"{path} cannot be read ({exc}); the run folder is damaged") from None
    return [e for e in entries if isinstance(e, dict)]


def _write_approvals(folder: Path, entries: list[dict[str, Any]]) -> None:
    from reports.pdfdoc import write_atomic

    text = json.dumps({"format": "gyrocal-approvals/1", "approvals": entries}, indent=2)
    write_atomic(folder / APPROVALS_FILE, (text + "\n").encode())


def approve(folder: Path, settings: LoadedSettings, *, by: str, role: str) -> dict[str, Any]:
    """Record and sign an approval; returns the new entry. UserError when the folder is
    altered, has no certificate, or the name is empty."""
    from reports.pdfdoc import write_atomic

    folder = Path(folder)
    name = by.strip()
    if not name or len(name) > MAX_NAME_CHARS:
        raise UserError(f"approver name must be 1-{MAX_NAME_CHARS} characters")
    result = verify_folder(folder, trusted_fingerprints(settings))
    if not result.intact:
        raise UserError(f"{folder} cannot be approved: " + "; ".join(result.problems))
    cert = folder / CERTIFICATE_FILE
    if not cert.is_file():
        raise UserError(f"{folder} has no certificate to approve; render it with "
                        "`station report RUN_FOLDER` first")
    entries = read_approvals(folder)
    entry = {"by": name, "role": role,
             "time_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
             "certificate_sha256": file_digest(cert)["sha256"]}
    identity = station_identity(settings)
    signed = sign_pdf_bytes(cert.read_bytes(), identity,
                            field_name=f"Approval-{len(entries) + 1}",
                            reason=approval_reason(entry), signer_name=name)
    write_atomic(cert, signed)
    _write_approvals(folder, [*entries, entry])
    seal(folder, identity, "approval")
    return entry
