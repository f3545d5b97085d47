"""PAdES signatures on certificates (pyHanko), each an incremental update of the PDF.

The station signs every certificate it issues (field "Station"); a quality engineer's
approval adds a second signature (field "Approval-N") after the first, so the first stays
valid and a reader (`pdfsig certificate.pdf`) lists both. The signing certificate is the
station's own (station/signing_keys.py): a self-signed one makes pdfsig say the
certificate is not trusted while the signature itself is valid.
"""

from __future__ import annotations

import asyncio
import io
import warnings
from concurrent.futures import ThreadPoolExecutor

from cryptography.utils import CryptographyDeprecationWarning

# pyHanko imports cryptography's DSA key type to recognise such keys; recent cryptography
# releases (51.0 here) warn on that import, on every command that signs. The station never
# signs with DSA (its key is RSA, station/signing_keys.py), so that one warning is the
# dependency's, not the user's: silenced here, at the import that raises it, nowhere else.
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message="DSA is deprecated",
                            category=CryptographyDeprecationWarning)
    from pyhanko.pdf_utils.incremental_writer import IncrementalPdfFileWriter
    from pyhanko.pdf_utils.misc import PdfError
    from pyhanko.sign import fields, signers
    from pyhanko.sign.general import SigningError

from station.signing_keys import SigningKeyError, StationIdentity

STATION_FIELD = "Station"
# room for the CMS signature (RSA-2048 and a one-certificate chain need about 2 KiB); given,
# so pyHanko does not make a trial signature first to size it (half the signing time)
SIGNATURE_BYTES = 16384


def _signer(identity: StationIdentity) -> signers.SimpleSigner:
    signer = signers.SimpleSigner.load(str(identity.key_path), str(identity.certificate_path))
    if signer is None:
        raise SigningKeyError(f"pyHanko cannot load the station key {identity.key_path} with "
                              f"{identity.certificate_path}; check both are PEM")
    return signer


def _in_event_loop() -> bool:
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return False
    return True


def sign_pdf_bytes(pdf: bytes, identity: StationIdentity, *, field_name: str, reason: str,
                   signer_name: str, location: str = "") -> bytes:
    """`pdf` with one more PAdES (B-B) signature appended as an incremental update.

    pyHanko's synchronous API runs its own asyncio loop; called from a thread that already
    runs one (an async web handler, a test's browser driver) it signs on a worker thread."""
    if _in_event_loop():
        with ThreadPoolExecutor(max_workers=1) as pool:
            return pool.submit(_sign, pdf, identity, field_name, reason, signer_name,
                               location).result()
    return _sign(pdf, identity, field_name, reason, signer_name, location)


def _sign(pdf: bytes, identity: StationIdentity, field_name: str, reason: str,
          signer_name: str, location: str) -> bytes:
    try:
        writer = IncrementalPdfFileWriter(io.BytesIO(pdf), strict=False)
        meta = signers.PdfSignatureMetadata(
            field_name=field_name,
            reason=reason,
            name=signer_name or None,
            location=location or None,
            md_algorithm="sha256",
            subfilter=fields.SigSeedSubFilter.PADES,
        )
        out = signers.sign_pdf(writer, meta, signer=_signer(identity),
                               bytes_reserved=SIGNATURE_BYTES)
    except (PdfError, SigningError, ValueError) as exc:
        raise SigningKeyError(f"could not sign the certificate PDF ({exc}); render it again "
                              "with `station report RUN_FOLDER`") from exc
    return out.getvalue()


def unsigned_revision(pdf: bytes) -> bytes:
    """The PDF as rendered, before any signature: its first revision (up to and including
    the first %%EOF line). Signing only appends, so this part is byte-identical for the
    same record however often it is signed."""
    end = pdf.find(b"%%EOF")
    if end < 0:
        return pdf
    end += len(b"%%EOF")
    while end < len(pdf) and pdf[end:end + 1] in (b"\r", b"\n"):
        end += 1
    return pdf[:end]
