"""`station verify` and `station approve`: tamper evidence of run folders.

    station verify RUN_FOLDER|RUN.tar.xz [--trust CERT.pem] [--station FILE]
        exit 0 intact, 1 altered (naming the file), 2 not a run folder (pinned); a run
        archive (`station archive`) is checked as its folder was
    station approve RUN_FOLDER --by NAME [--remark TEXT] [--station FILE]
        a quality engineer's approval: shown on the certificate, second PDF signature,
        approvals.json, new manifest (a run that did not PASS needs --remark)
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from station.errors import UserError
from station.manifest import Status, Verification, verify_folder
from station.run_archive import verify_archive
from station.settings import LoadedSettings
from station.signing_keys import certificate_fingerprint, load_trusted_certificate
from station.station_file import load_settings

log = logging.getLogger(__name__)

ORIGINS = {"run": "at the end of the run", "report": "by `station report` (not at the run)",
           "approval": "after a quality approval"}


AGAIN = {"report": "by `station report`", "approval": "after a quality approval",
         "run": "at the end of the run"}


def sealed_text(result: Verification) -> str:
    """When the folder's evidence starts (its first sealing) and what sealed it last."""
    first = result.first_origin or result.origin
    text = "sealed " + ORIGINS.get(first, first or "unknown")
    if result.origin and result.origin != first:
        text += ", sealed again " + AGAIN.get(result.origin, result.origin)
    return text


def station_settings(path: str | None) -> object | None:
    try:
        return load_settings(Path(path) if path else None)
    except Exception as exc:  # verify still works without a station file: any valid signer
        if path:
            raise UserError(f"--station {path}: {exc}") from None
        log.info("no station settings (%s)", exc)
        return None


def trusted_for(args: argparse.Namespace) -> tuple[set[str] | None, str]:
    """The fingerprints to accept and a sentence saying where they came from."""
    # station.certify loads pyhanko (PDF signing, ~270 modules): only for the commands that
    # check signatures, not at every `station` start (station.cli.main imports every command group)
    from station.certify import trusted_fingerprints

    if args.trust:
        cert = load_trusted_certificate(Path(args.trust))
        return {certificate_fingerprint(cert)}, f"trusting {args.trust}"
    settings = station_settings(args.station)
    if isinstance(settings, LoadedSettings):
        trusted = trusted_fingerprints(settings)
        if trusted is not None:
            return trusted, "trusting this station's certificate"
    return None, ("no station certificate to trust here: the signature is checked against "
                  "the certificate in the manifest only (give --trust CERT.pem)")


def cmd_verify(args: argparse.Namespace) -> int:
    folder = Path(args.run_folder)
    trusted, basis = trusted_for(args)
    result = (verify_folder(folder, trusted) if folder.is_dir() or not folder.exists()
              else verify_archive(folder, trusted))
    if result.status is Status.NOT_A_RUN_FOLDER:
        for p in result.problems:
            print(p, file=sys.stderr)
        return int(Status.NOT_A_RUN_FOLDER)
    if result.intact:
        print(f"{folder}: intact (signed by {result.signer_fingerprint}, {sealed_text(result)};"
              f" {basis})")
        return int(Status.INTACT)
    print(f"{folder}: ALTERED: " + ", ".join(result.altered_files))
    for p in result.problems:
        print(f"  {p}")
    return int(Status.ALTERED)


def cmd_approve(args: argparse.Namespace) -> int:
    from station.approvals import approve  # pyhanko: only when approving (see trusted_for)

    settings = station_settings(args.station)
    if not isinstance(settings, LoadedSettings):
        raise UserError("no station settings: give --station FILE (its key signs approvals)")
    entry = approve(Path(args.run_folder), settings, by=args.by, role="quality",
                    remark=args.remark or "")
    print(f"{args.run_folder}: approved by {entry['by']} at {entry['time_utc']}")
    return 0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "verify", help="check a run folder or run archive against its signed manifest")
    p.add_argument("run_folder", metavar="RUN_FOLDER", help="a run folder or its archive "
                   "(RUN.tar.xz, from `station archive`)")
    p.add_argument("--trust", metavar="CERT.pem",
                   help="accept only this signer (default: the station's own certificate)")
    p.add_argument("--station", metavar="FILE", help="station file (default: config/station.yaml)")
    p.set_defaults(handler=cmd_verify)

    p = subparsers.add_parser("approve", help="record a quality engineer's approval of a run")
    p.add_argument("run_folder", metavar="RUN_FOLDER")
    p.add_argument("--by", required=True, metavar="NAME", help="the approving quality engineer")
    p.add_argument("--remark", metavar="TEXT",
                   help="why the run is approved (needed unless it PASSed); on the certificate")
    p.add_argument("--station", metavar="FILE", help="station file (default: config/station.yaml)")
    p.set_defaults(handler=cmd_approve)
