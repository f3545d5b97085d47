"""Issuing a run's certificate: number it, render it, sign it, seal the folder.

    finish_run_folder(folder, settings, certificate=True)   # at the end of every run
    issue_certificate(folder, settings, origin="report")    # `station report`

The certificate number is the station id and a sequence from a persistent counter
(station.yaml `signing: counter:`), e.g. EOL-SIM-01-000042, given once per run and kept in
record.json (`certificate_number`), so re-rendering a run keeps its number. Every
certificate gets the station's PAdES signature; approvals already recorded in
approvals.json are signed again after it (station/approvals.py). The folder's manifest
(station/manifest.py) is written last, over the files as they then are.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path

from procedures.runtime.record import (
    CERTIFICATE_FILE,
    CertificateContext,
    ReferenceStandard,
    Verdict,
    read_record,
    write_record,
)
from station.manifest import APPROVALS_FILE, seal
from station.pdf_signing import STATION_FIELD, sign_pdf_bytes
from station.settings import FixtureSettings, InstrumentSettings, LoadedSettings
from station.signing_keys import (
    StationIdentity,
    certificate_fingerprint,
    load_or_create_identity,
    load_trusted_certificate,
)

log = logging.getLogger(__name__)

NUMBER_DIGITS = 6


def station_identity(settings: LoadedSettings) -> StationIdentity:
    s = settings.settings
    return load_or_create_identity(settings.resolve(s.signing.key),
                                   settings.resolve(s.signing.certificate), s.station.id)


def trusted_fingerprints(settings: LoadedSettings) -> set[str] | None:
    """The signers this station accepts: its own certificate; None when it has none yet."""
    path = settings.resolve(settings.settings.signing.certificate)
    if not path.is_file():
        return None
    return {certificate_fingerprint(load_trusted_certificate(path))}


def next_certificate_number(counter_path: Path, station_id: str) -> str:
    """The next number of the station's sequence; safe across processes (file lock)."""
    counter_path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(counter_path, os.O_RDWR | os.O_CREAT, 0o644)
    with os.fdopen(fd, "r+", encoding="utf-8") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        text = fh.read().strip()
        try:
            last = int(json.loads(text)["last"]) if text else 0
        except (ValueError, KeyError, TypeError):
            raise ValueError(f"certificate counter {counter_path} is unreadable; restore it "
                             "from backup (numbers must not repeat)") from None
        number = last + 1
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps({"station": station_id, "last": number}) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    return f"{station_id}-{number:0{NUMBER_DIGITS}d}"


def certificate_context(settings: LoadedSettings, decision_rule: str) -> CertificateContext:
    """Decision rule, reference standards and ambient as the station file gives them now."""
    s = settings.settings
    roles: dict[str, InstrumentSettings | FixtureSettings] = {
        "rate_table": s.instruments.rate_table, "chamber": s.instruments.chamber,
        "supply": s.instruments.supply, "fixture": s.instruments.fixture}
    standards = [
        ReferenceStandard(role=role, calibration_certificate=inst.calibration_certificate,
                          reference_uncertainty=inst.reference_uncertainty,
                          calibration_due=str(inst.calibration_due)
                          if inst.calibration_due else None)
        for role, inst in roles.items()
    ]
    ambient = s.ambient
    return CertificateContext(
        decision_rule=decision_rule,
        reference_standards=standards,
        ambient_temperature_c=ambient.temperature_c if ambient else None,
        ambient_humidity_pct=ambient.humidity_pct if ambient else None,
        ambient_source="station file (ambient:)" if ambient else "",
    )


def ensure_certificate_number(folder: Path, settings: LoadedSettings,
                              decision_rule: str = "") -> str:
    """The run's certificate number, given (and written into record.json with the
    certificate context) if it has none. '' when the record cannot be read or the run has
    not finished."""
    try:
        record = read_record(folder)
    except (OSError, ValueError):
        return ""
    if record.certificate_number or record.verdict is Verdict.RUNNING:
        return record.certificate_number
    s = settings.settings
    record.certificate_number = next_certificate_number(
        settings.resolve(s.signing.counter), s.station.id)
    if record.certificate_context is None:
        record.certificate_context = certificate_context(settings, decision_rule)
    write_record(folder, record)
    return record.certificate_number


def _recorded_number(folder: Path) -> str:
    """The number given at the end of the run; a re-render never gives one (a record from
    before numbering keeps saying so, and renders as it did)."""
    try:
        return read_record(folder).certificate_number
    except (OSError, ValueError):
        return ""


def _approvals(folder: Path) -> list[dict[str, str]]:
    path = folder / APPROVALS_FILE
    if not path.is_file():
        return []
    try:
        entries = json.loads(path.read_text(encoding="utf-8")).get("approvals", [])
    except (OSError, ValueError, AttributeError):
        return []
    return [e for e in entries if isinstance(e, dict)]


def signed_certificate(pdf: bytes, identity: StationIdentity, station_id: str,
                       number: str, approvals: list[dict[str, str]]) -> bytes:
    """The station's signature, then one per recorded approval, each incremental."""
    what = f"certificate {number}" if number else "certificate"
    pdf = sign_pdf_bytes(pdf, identity, field_name=STATION_FIELD,
                         reason=f"{what} issued by test station {station_id}",
                         signer_name=station_id)
    for n, entry in enumerate(approvals, start=1):
        pdf = sign_pdf_bytes(pdf, identity, field_name=f"Approval-{n}",
                             reason=approval_reason(entry), signer_name=str(entry.get("by", "")))
    return pdf


def approval_reason(entry: dict[str, str]) -> str:
    return (f"approved by {entry.get('by', '?')} ({entry.get('role', 'quality')}) at "
            f"{entry.get('time_utc', '?')}")


def issue_certificate(folder: Path, settings: LoadedSettings, *, origin: str,
                      decision_rule: str = "") -> Path:
    """Number, render, sign and seal; returns the certificate's path. Raises on I/O or key
    problems (SigningKeyError, OSError)."""
    # reportlab (PDF): loaded only when a report is drawn
    from reports.certificate import certificate_bytes
    from reports.pdfdoc import write_atomic

    identity = station_identity(settings)
    number = (ensure_certificate_number(folder, settings, decision_rule) if origin == "run"
              else _recorded_number(folder))
    pdf = signed_certificate(certificate_bytes(folder), identity, settings.settings.station.id,
                             number, _approvals(folder))
    path = write_atomic(folder / CERTIFICATE_FILE, pdf)
    seal(folder, identity, origin)
    return path


def finish_run_folder(folder: Path, settings: LoadedSettings, *, certificate: bool,
                      decision_rule: str = "") -> Path | None:
    """At the end of a run: the signed certificate (when wanted) and the manifest. Never
    raises: the record stands without them, and the failure is logged. `decision_rule`: the
    product's, stated on the certificate."""
    try:
        if certificate:
            return issue_certificate(folder, settings, origin="run", decision_rule=decision_rule)
        ensure_certificate_number(folder, settings, decision_rule)
        seal(folder, station_identity(settings), "run")
    except Exception as exc:
        log.error("certificate or manifest for %s failed: %s", folder, exc)
    return None


def recovered_run_sealer(settings: LoadedSettings) -> Callable[[Path], None]:
    """For crash recovery (station/run_folder.py): a crashed run, once marked ERROR, is
    numbered and sealed as any finished run is (no certificate: it has no result)."""

    def seal_recovered(folder: Path) -> None:
        finish_run_folder(folder, settings, certificate=False)

    return seal_recovered
