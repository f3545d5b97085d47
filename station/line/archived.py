"""The dashboard's certificate of an archived run: read from inside its archive.

`station archive` points a run's `folder` at `ARCHIVE#RUN` (station/run_archive.py); the
certificate is that archive's member RUN/certificate.pdf, read without unpacking the rest.
"""

from __future__ import annotations

from pathlib import Path

from fastapi.responses import JSONResponse, Response

from procedures.runtime.record import CERTIFICATE_FILE
from station.run_archive import read_member

MAX_CERTIFICATE_BYTES = 64 << 20  # a certificate is a few hundred kB


def archived_certificate(run_id: str, archive: Path, run: str) -> Response:
    """The PDF, or a 404 saying why it is not reachable from here."""
    pdf = read_member(archive, run, CERTIFICATE_FILE, MAX_CERTIFICATE_BYTES)
    if pdf is None:
        return JSONResponse({"error": (
            f"the certificate of run {run_id} is not reachable from here: {CERTIFICATE_FILE} "
            f"in the archive {archive} (share the station's archive folder with this computer "
            "at the same path; check it with `station verify`)")}, status_code=404)
    name = f"{run_id}-{CERTIFICATE_FILE}"
    return Response(pdf, media_type="application/pdf",
                    headers={"Content-Disposition": f'attachment; filename="{name}"'})
