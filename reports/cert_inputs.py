"""Loading what a certificate is built from, turning every defect into a stated problem.

A certificate is issued for every run folder, whatever state it is in: a missing or broken
record.json or raw data file, or raw data that no longer matches the SHA-256 the record
holds, makes the certificate's verdict ERROR with the problem spelled out, never a traceback.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from procedures.runtime.rawdata import RawData, RawDataError, file_sha256, read_raw
from procedures.runtime.record import RAW_DATA_FILE, RunRecord, Verdict, read_record

log = logging.getLogger(__name__)

APPROVALS_FILE = "approvals.json"  # written by station/approvals.py, sealed with the folder


@dataclass
class CertificateInputs:
    folder: Path
    record: RunRecord | None
    raw: RawData | None
    raw_path: Path
    raw_sha256: str | None
    problems: list[str] = field(default_factory=list)
    # quality approvals ({by, role, time_utc, remark}), shown in the sign-off box
    approvals: list[dict[str, Any]] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        """The verdict the certificate shows: the record's, or ERROR when inputs are broken."""
        if self.record is None or self.problems:
            return Verdict.ERROR.value
        if self.record.verdict == Verdict.RUNNING:
            return Verdict.ERROR.value
        return self.record.verdict.value

    @property
    def reason(self) -> str:
        parts = list(self.problems)
        if self.record is not None:
            if self.record.verdict == Verdict.RUNNING:
                parts.insert(
                    0, "the run never finished: record.json still says RUNNING (station crash?)"
                )
            if self.record.reason:
                parts.append(f"the run's own reason: {self.record.reason}" if parts
                             else self.record.reason)
            if self.problems and self.record.verdict not in (Verdict.ERROR, Verdict.RUNNING):
                parts.append(
                    f"the run itself recorded {self.record.verdict.value}, which cannot be "
                    "confirmed from the data"
                )
        return "; ".join(parts)


def _raw_path(folder: Path, record: RunRecord | None) -> Path:
    if record is not None and record.raw_data is not None and record.raw_data.path:
        named = Path(record.raw_data.path)
        candidate = named if named.is_absolute() else folder / named
        if candidate.exists():
            return candidate
        return folder / named.name
    return folder / RAW_DATA_FILE


def read_approvals(folder: Path) -> list[dict[str, Any]]:
    """The approvals recorded in the folder's approvals.json; none when there is no such
    file or it cannot be read (station/approvals.py refuses to approve a damaged one)."""
    path = Path(folder) / APPROVALS_FILE
    if not path.is_file():
        return []
    try:
        entries = json.loads(path.read_text(encoding="utf-8")).get("approvals", [])
    except (OSError, ValueError, AttributeError) as exc:
        log.warning("approvals of %s not shown: %s", folder, exc)
        return []
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def load_inputs(folder: Path,
                approvals: list[dict[str, Any]] | None = None) -> CertificateInputs:
    """Read record.json and the raw data of a run folder, collecting what is wrong.
    `approvals`: the approvals to show (default: the folder's approvals.json)."""
    problems: list[str] = []
    record: RunRecord | None = None
    try:
        record = read_record(folder)
    except ValueError as exc:
        problems.append(f"{exc}; re-run the part or restore record.json from the results store")
    raw_path = _raw_path(folder, record)
    raw: RawData | None = None
    sha: str | None = None
    if not raw_path.exists():
        problems.append(
            f"raw data file {raw_path.name} is missing from {folder}; the results cannot be "
            "traced to data: re-run the part"
        )
    else:
        sha = file_sha256(raw_path)
        try:
            raw = read_raw(raw_path)
        except RawDataError as exc:
            problems.append(f"raw data unreadable: {exc}; re-run the part")
        recorded = record.raw_data.sha256 if record and record.raw_data else ""
        if recorded and sha != recorded:
            problems.append(
                f"raw data {raw_path.name} does not match the SHA-256 in record.json "
                f"(file {sha[:16]}..., record {recorded[:16]}...): the data was altered or "
                "replaced after the run"
            )
    for p in problems:
        log.warning("certificate for %s: %s", folder, p)
    shown = read_approvals(folder) if approvals is None else approvals
    return CertificateInputs(folder, record, raw, raw_path, sha, problems, shown)
