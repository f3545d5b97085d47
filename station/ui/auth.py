"""Engineer password: stored only as a salted scrypt hash in station.yaml, checked here.

Format of the stored string (one line, safe in YAML):
    scrypt$<n>$<r>$<p>$<salt hex>$<hash hex>
Sessions are random tokens kept in memory: a restart logs everybody out, which suits a
station that is restarted at shift change.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import time
from dataclasses import dataclass, field

_SCHEME = "scrypt"
_N, _R, _P = 2**14, 8, 1
_DKLEN = 32


def hash_password(password: str, *, n: int = _N, r: int = _R, p: int = _P) -> str:
    """Return the string to store in station.yaml under `ui.engineer_password_hash`."""
    if len(password) < 6:
        raise ValueError("engineer password too short: use at least 6 characters")
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=_DKLEN)
    return f"{_SCHEME}${n}${r}${p}${salt.hex()}${digest.hex()}"


def check_hash_format(stored: str) -> None:
    """Raise ValueError saying how to fix a malformed stored hash."""
    parts = stored.split("$")
    if len(parts) != 6 or parts[0] != _SCHEME:
        raise ValueError(
            "ui.engineer_password_hash in station.yaml is not a scrypt hash; "
            "make one with `station ui --hash-password` and paste its output there"
        )
    try:
        int(parts[1]), int(parts[2]), int(parts[3])
        bytes.fromhex(parts[4]), bytes.fromhex(parts[5])
    except ValueError as exc:
        raise ValueError(
            "ui.engineer_password_hash in station.yaml is damaged (bad number or hex); "
            "make a new one with `station ui --hash-password`"
        ) from exc


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


@dataclass
class Sessions:
    """Engineer sessions: token -> expiry (monotonic seconds)."""

    lifetime_s: float = 8 * 3600.0  # one shift
    _expiry: dict[str, float] = field(default_factory=dict)

    def open(self) -> str:
        token = secrets.token_urlsafe(24)
        self._expiry[token] = time.monotonic() + self.lifetime_s
        return token

    def is_engineer(self, token: str | None) -> bool:
        if not token:
            return False
        expiry = self._expiry.get(token)
        if expiry is None:
            return False
        if expiry < time.monotonic():
            del self._expiry[token]
            return False
        return True

    def close(self, token: str | None) -> None:
        if token:
            self._expiry.pop(token, None)


@dataclass
class LoginThrottle:
    """After `limit` wrong passwords within `window_s`, refuse logins for `lockout_s`."""

    limit: int = 5
    window_s: float = 60.0
    lockout_s: float = 60.0
    _failures: list[float] = field(default_factory=list)
    _locked_until: float = 0.0

    def wait_s(self) -> float:
        return max(0.0, self._locked_until - time.monotonic())

    def failed(self) -> None:
        now = time.monotonic()
        self._failures = [t for t in self._failures if now - t < self.window_s] + [now]
        if len(self._failures) >= self.limit:
            self._locked_until = now + self.lockout_s
            self._failures = []

    def reset(self) -> None:
        self._failures = []
