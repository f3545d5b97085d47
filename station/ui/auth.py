"""Secrets of the browser station: the engineer password and the operators' PINs and badges.

Stored only as salted hashes in station.yaml, checked here. Formats (one line, safe in YAML):
    scrypt$<n>$<r>$<p>$<salt hex>$<hash hex>      engineer password, operator PIN
    sha256$<salt hex>$<hash hex>                  operator badge code (looked up among all
                                                  operators at each scan, so a fast hash)
Sessions and login throttling are in station/ui/sessions.py.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass

_SCHEME = "scrypt"
_N, _R, _P = 2**14, 8, 1
_DKLEN = 32


def hash_password(
    password: str,
    *,
    n: int = _N,
    r: int = _R,
    p: int = _P,
    min_chars: int = 6,
    what: str = "engineer password",
) -> str:
    """Return the string to store in station.yaml under `ui.engineer_password_hash`."""
    if len(password) < min_chars:
        raise ValueError(f"{what} too short: use at least {min_chars} characters")
    if len(password) > 256:
        raise ValueError(f"{what} too long: use at most 256 characters")
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=_DKLEN)
    return f"{_SCHEME}${n}${r}${p}${salt.hex()}${digest.hex()}"


def hash_pin(pin: str) -> str:
    """Return the string to store under an operator's `pin_hash` (scrypt, like the password)."""
    return hash_password(pin, min_chars=4, what="PIN")


def check_hash_format(
    stored: str,
    field: str = "ui.engineer_password_hash",
    command: str = "station ui --hash-password",
) -> None:
    """Raise ValueError saying how to fix a malformed stored hash."""
    parts = stored.split("$")
    if len(parts) != 6 or parts[0] != _SCHEME:
        raise ValueError(
            f"{field} in station.yaml is not a scrypt hash; "
            f"make one with `{command}` and paste its output there"
        )
    try:
        n, r, p = int(parts[1]), int(parts[2]), int(parts[3])
        bytes.fromhex(parts[4]), bytes.fromhex(parts[5])
    except ValueError as exc:
        raise ValueError(
            f"{field} in station.yaml is damaged (bad number or hex); "
            f"make a new one with `{command}`"
        ) from exc
    if not (2 <= n <= 2**20 and n & (n - 1) == 0 and 1 <= r <= 32 and 1 <= p <= 16):
        raise ValueError(
            f"{field} in station.yaml has scrypt costs out of range (n a power of two up to "
            f"2^20, r 1..32, p 1..16); make a new one with `{command}`"
        )


def hash_badge(badge: str) -> str:
    """Return the string to store under an operator's `badge_hash`."""
    code = badge.strip()
    if not 4 <= len(code) <= 128:
        raise ValueError("badge code must be 4..128 characters; scan the badge again")
    salt = secrets.token_bytes(16)
    return f"sha256${salt.hex()}${hashlib.sha256(salt + code.encode()).hexdigest()}"


def check_badge_hash(stored: str, field: str) -> None:
    parts = stored.split("$")
    try:
        ok = len(parts) == 3 and parts[0] == "sha256" and len(bytes.fromhex(parts[2])) == 32
        bytes.fromhex(parts[1])
    except ValueError:
        ok = False
    if not ok:
        raise ValueError(
            f"{field} in station.yaml is not a badge hash; make one with "
            "`station ui --hash-badge` and paste its output there"
        )


def badge_matches(badge: str, stored: str) -> bool:
    _, salt_hex, hash_hex = stored.split("$")
    digest = hashlib.sha256(bytes.fromhex(salt_hex) + badge.strip().encode()).digest()
    return hmac.compare_digest(digest, bytes.fromhex(hash_hex))


@dataclass(frozen=True)
class Operator:
    name: str
    pin_hash: str | None = None
    badge_hash: str | None = None
    role: str = "operator"  # or "quality": may approve runs (station/ui/approval_routes.py)


_DUMMY_PIN_HASH = "scrypt$16384$8$1$" + "00" * 16 + "$" + "00" * 32


@dataclass(frozen=True)
class OperatorBook:
    """The operators of station.yaml; empty means an open station (sign-in by name only)."""

    operators: tuple[Operator, ...] = ()

    @property
    def open(self) -> bool:
        return not self.operators

    def check(self) -> None:
        """ValueError naming the first damaged hash."""
        for i, o in enumerate(self.operators):
            if o.pin_hash:
                check_hash_format(
                    o.pin_hash, f"ui.operators[{i}].pin_hash", "station ui --hash-pin"
                )
            if o.badge_hash:
                check_badge_hash(o.badge_hash, f"ui.operators[{i}].badge_hash")

    def by_badge(self, badge: str) -> Operator | None:
        found = None
        for o in self.operators:  # every entry compared: the time does not say which matched
            if o.badge_hash and badge_matches(badge, o.badge_hash) and found is None:
                found = o
        return found

    def by_pin(self, name: str, pin: str) -> Operator | None:
        wanted = name.strip().casefold()
        match = next((o for o in self.operators if o.name.casefold() == wanted), None)
        stored = match.pin_hash if match is not None and match.pin_hash else _DUMMY_PIN_HASH
        ok = verify_password(pin, stored)  # an unknown name costs the same time
        return match if ok and match is not None and match.pin_hash else None


def verify_password(password: str, stored: str) -> bool:
    """True when `password` matches the stored hash; constant-time comparison."""
    check_hash_format(stored)
    _, n, r, p, salt_hex, hash_hex = stored.split("$")
    expected = bytes.fromhex(hash_hex)
    digest = hashlib.scrypt(
        password.encode(),
        salt=bytes.fromhex(salt_hex),
        n=int(n),
        r=int(r),
        p=int(p),
        dklen=len(expected),
        maxmem=128 * int(n) * int(r) * 2 + 1024 * 1024,
    )
    return hmac.compare_digest(digest, expected)


