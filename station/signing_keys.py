"""The station's signing identity: a private key and its X.509 certificate.

station.yaml's `signing:` section names the key and certificate files (PEM, relative to the
station file). When neither exists they are made on first use: an RSA-2048 key (file mode
0600) and a self-signed certificate whose subject is the station id. A key and certificate
issued by the factory's own certificate authority can be put there instead; the station
then signs with those. The certificate's SHA-256 fingerprint names the signer in every
manifest (station/manifest.py) and PDF signature (station/pdf_signing.py).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import padding, rsa
from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes
from cryptography.x509.oid import NameOID

from station.errors import UserError

log = logging.getLogger(__name__)

KEY_BITS = 2048
CERT_VALID_DAYS = 20 * 365


class SigningKeyError(UserError):
    """The station's key or certificate cannot be read, made or used."""


@dataclass(frozen=True)
class StationIdentity:
    key_path: Path
    certificate_path: Path
    key: rsa.RSAPrivateKey
    certificate: x509.Certificate

    @property
    def fingerprint(self) -> str:
        return certificate_fingerprint(self.certificate)

    @property
    def subject(self) -> str:
        return self.certificate.subject.rfc4514_string()

    def certificate_pem(self) -> str:
        return self.certificate.public_bytes(serialization.Encoding.PEM).decode("ascii")

    def sign(self, data: bytes) -> bytes:
        """RSA PKCS#1 v1.5 signature of `data` with SHA-256."""
        return self.key.sign(data, padding.PKCS1v15(), hashes.SHA256())


def certificate_fingerprint(cert: x509.Certificate) -> str:
    """SHA-256 of the certificate's DER bytes, lower-case hex."""
    return cert.fingerprint(hashes.SHA256()).hex()


def _write_private(path: Path, data: bytes, mode: int) -> None:
    """Write by temp + rename with `mode`; never replaces an existing file (another
    process that made the key first wins, and both then use its key)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), mode)
            fh.write(data)
        with contextlib.suppress(FileExistsError):
            os.link(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def _self_signed(key: rsa.RSAPrivateKey, common_name: str) -> x509.Certificate:
    name = x509.Name([
        x509.NameAttribute(NameOID.COMMON_NAME, common_name[:64] or "gyrocal station"),
        x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, "gyrocal-station test station"),
    ])
    now = dt.datetime.now(dt.UTC).replace(microsecond=0)
    return (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(days=1))
        .not_valid_after(now + dt.timedelta(days=CERT_VALID_DAYS))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(digital_signature=True, content_commitment=True,
                          key_encipherment=False, data_encipherment=False, key_agreement=False,
                          key_cert_sign=False, crl_sign=False, encipher_only=False,
                          decipher_only=False),
            critical=True,
        )
        .sign(key, hashes.SHA256())
    )


# parsed keys by the SHA-256 of their PEM: parsing checks the RSA key (~0.2 s), and a load of
# 32 parts signs 32 manifests with the same key; a changed file is a new entry
_PARSED_KEYS: dict[bytes, rsa.RSAPrivateKey] = {}


def _load_key(path: Path) -> rsa.RSAPrivateKey:
    try:
        pem = path.read_bytes()
        cached = _PARSED_KEYS.get(hashlib.sha256(pem).digest())
        if cached is not None:
            return cached
        key: PrivateKeyTypes = serialization.load_pem_private_key(pem, None)
    except (OSError, ValueError, TypeError) as exc:
        raise SigningKeyError(
            f"station signing key {path} cannot be read ({exc}); give an unencrypted PEM "
            "RSA key, or remove it (and its certificate) to have a new one made"
        ) from None
    if not isinstance(key, rsa.RSAPrivateKey):
        raise SigningKeyError(f"station signing key {path} is not an RSA key; give an RSA "
                              "key (PAdES readers such as pdfsig all accept RSA)")
    _PARSED_KEYS[hashlib.sha256(pem).digest()] = key
    return key


def _load_certificate(path: Path, key: rsa.RSAPrivateKey) -> x509.Certificate:
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise SigningKeyError(f"station certificate {path} cannot be read ({exc}); give a "
                              "PEM certificate of the signing key") from None
    pub = key.public_key().public_numbers()
    cert_pub = cert.public_key()
    if not isinstance(cert_pub, rsa.RSAPublicKey) or cert_pub.public_numbers() != pub:
        raise SigningKeyError(f"station certificate {path} is not the certificate of the "
                              "signing key; give the matching pair in station.yaml signing:")
    return cert


def load_or_create_identity(key_path: Path, certificate_path: Path,
                            common_name: str) -> StationIdentity:
    """The station's key and certificate, made on first use (key 0600, self-signed cert)."""
    key_path, certificate_path = Path(key_path), Path(certificate_path)
    try:
        if not key_path.exists():
            new_key = rsa.generate_private_key(public_exponent=65537, key_size=KEY_BITS)
            _write_private(key_path, new_key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                serialization.NoEncryption()), 0o600)
            log.warning("made a new station signing key %s", key_path)
        key = _load_key(key_path)
        if not certificate_path.exists():
            cert = _self_signed(key, common_name)
            _write_private(certificate_path, cert.public_bytes(serialization.Encoding.PEM),
                           0o644)
            log.warning("made a self-signed station certificate %s", certificate_path)
    except OSError as exc:
        raise SigningKeyError(f"cannot make the station signing key in {key_path.parent} "
                              f"({exc.strerror}); check the folder's permissions") from None
    return StationIdentity(key_path=key_path, certificate_path=certificate_path, key=key,
                           certificate=_load_certificate(certificate_path, key))


# a PEM certificate is 1-2 kB (a chain a few); `--trust` reads no more than this
MAX_CERTIFICATE_BYTES = 64 * 1024


def load_trusted_certificate(path: Path) -> x509.Certificate:
    try:
        with Path(path).open("rb") as fh:
            data = fh.read(MAX_CERTIFICATE_BYTES + 1)
    except OSError as exc:
        raise SigningKeyError(f"trusted certificate {path} cannot be read "
                              f"({exc.strerror or exc}); give a PEM certificate") from None
    if len(data) > MAX_CERTIFICATE_BYTES:
        raise SigningKeyError(f"trusted certificate {path} is larger than "
                              f"{MAX_CERTIFICATE_BYTES // 1024} kB; give a PEM certificate")
    try:
        return x509.load_pem_x509_certificate(data)
    except ValueError as exc:
        text = " ".join(str(exc).split())[:200]
        raise SigningKeyError(f"trusted certificate {path} cannot be read ({text}); give a "
                              "PEM certificate") from None
