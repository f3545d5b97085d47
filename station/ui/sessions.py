"""Browser sessions and the per-client login throttle.

A session is a random token in an HttpOnly, SameSite=Strict cookie, with its own CSRF token
(sent back by the page in a header on every state-changing request), the operator signed in
on it and whether the engineer logged in on it. Sessions live in memory: a restart signs
everybody out, which suits a station restarted at shift change.

Wrong PINs, badges and passwords are counted per client (per session), with a backoff that
doubles at each further failure, so one client's guesses never lock out another. A client
that throws its session away to start afresh is caught by a per-address budget: a session
opened from an address with many recent failures starts under that address's wait for signing
in. The lockout limits sign-in attempts only: reading the session (a reloaded screen) and
aborting a run are never locked out, and sessions the address already holds, such as the
station's own screen, keep signing in.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field

SESSION_LIFETIME_S = 12 * 3600.0  # one shift and then some
MAX_SESSIONS = 2000  # beyond this the oldest nobody signed in on is dropped: memory bounded
NEW_SESSIONS_PER_MIN = 60  # per address: a page load opens one; a flood is refused


class TooManySessions(Exception):
    """An address opened sessions faster than any screen does."""


@dataclass
class Session:
    token: str
    csrf: str
    address: str
    expires_s: float
    operator: str = ""
    engineer: bool = False
    quality: bool = False  # the signed-in operator has the quality role


@dataclass
class Sessions:
    lifetime_s: float = SESSION_LIFETIME_S
    max_sessions: int = MAX_SESSIONS
    per_minute: int = NEW_SESSIONS_PER_MIN
    _by_token: OrderedDict[str, Session] = field(default_factory=OrderedDict)
    _opened: dict[str, list[float]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def open(self, address: str, *, renewal: bool = False) -> Session:
        """A new session; TooManySessions when `address` opens them faster than a screen."""
        now = time.monotonic()
        session = Session(
            token=secrets.token_urlsafe(32),
            csrf=secrets.token_urlsafe(32),
            address=address,
            expires_s=now + self.lifetime_s,
        )
        with self._lock:
            if not renewal:
                recent = [t for t in self._opened.get(address, []) if now - t < 60.0]
                if len(recent) >= self.per_minute:
                    raise TooManySessions(address)
                self._opened[address] = recent + [now]
                if len(self._opened) > self.max_sessions:
                    self._opened.pop(next(iter(self._opened)))
            self._by_token[session.token] = session
            while len(self._by_token) > self.max_sessions:
                self._evict_one()
        return session

    def _evict_one(self) -> None:
        """The oldest session nobody signed in on goes first (a flood of fresh sessions
        cannot push out the screen an operator is signed in on)."""
        for token, candidate in self._by_token.items():
            if not candidate.operator and not candidate.engineer:
                del self._by_token[token]
                return
        self._by_token.popitem(last=False)

    def get(self, token: str | None) -> Session | None:
        if not token or len(token) > 128:
            return None
        with self._lock:
            session = self._by_token.get(token)
            if session is None:
                return None
            if session.expires_s < time.monotonic():
                del self._by_token[token]
                return None
            return session

    def renew(self, session: Session) -> Session:
        """The same sign-in under new tokens (after a change of who is signed in, so that a
        token seen before the sign-in is worth nothing after it)."""
        fresh = self.open(session.address, renewal=True)
        fresh.operator, fresh.engineer = session.operator, session.engineer
        fresh.quality = session.quality
        self.close(session.token)
        return fresh

    def close(self, token: str | None) -> None:
        if token:
            with self._lock:
                self._by_token.pop(token, None)


@dataclass
class _Failures:
    count: int = 0
    locked_until_s: float = 0.0
    last_s: float = 0.0


@dataclass
class LoginThrottle:
    """Failures per key: `free` tries, then a lockout of base_s, doubling up to max_s.

    Keys are a session token (one client) or "addr:" + an address (the budget for opening new
    sessions). A key's count is forgotten `forget_s` after its last failure.
    """

    free: int = 3
    base_s: float = 2.0
    max_s: float = 300.0
    forget_s: float = 900.0
    address_free: int = 20
    max_keys: int = 10_000
    _keys: OrderedDict[str, _Failures] = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def wait_s(self, key: str) -> float:
        with self._lock:
            entry = self._entry(key, create=False)
            return 0.0 if entry is None else max(0.0, entry.locked_until_s - time.monotonic())

    def failed(self, key: str, free: int | None = None) -> float:
        """Count a failure; returns the wait now imposed on `key` (0 while tries are free)."""
        allowed = self.free if free is None else free
        now = time.monotonic()
        with self._lock:
            entry = self._entry(key, create=True)
            assert entry is not None
            entry.count += 1
            entry.last_s = now
            over = entry.count - allowed
            if over > 0:  # the wait itself: (now + wait) - now may round past it
                wait = min(self.max_s, self.base_s * 2 ** min(over - 1, 30))
                entry.locked_until_s = now + wait
                return float(wait)
            return max(0.0, entry.locked_until_s - now)

    def failed_from(self, session_token: str, address: str) -> float:
        """A failure by one client: counted for it and towards its address's budget."""
        self.failed("addr:" + address, free=self.address_free)
        return self.failed(session_token)

    def inherit(self, key: str, source: str) -> float:
        """`key` (a new session) starts under `source`'s wait (its address's), with its free
        tries spent: throwing a session away buys no guesses, yet the new session still reads
        and aborts. Returns the wait carried over."""
        with self._lock:
            origin = self._entry(source, create=False)
            now = time.monotonic()
            if origin is None or origin.locked_until_s <= now:
                return 0.0
            entry = self._entry(key, create=True)
            assert entry is not None
            entry.count = max(entry.count, self.free)
            entry.last_s = now
            entry.locked_until_s = max(entry.locked_until_s, origin.locked_until_s)
            return entry.locked_until_s - now

    def reset(self, key: str) -> None:
        with self._lock:
            self._keys.pop(key, None)

    def _entry(self, key: str, *, create: bool) -> _Failures | None:
        now = time.monotonic()
        entry = self._keys.get(key)
        if entry is not None and now - entry.last_s > self.forget_s and entry.locked_until_s < now:
            del self._keys[key]
            entry = None
        if entry is None and create:
            entry = self._keys[key] = _Failures()
            while len(self._keys) > self.max_keys:
                self._keys.popitem(last=False)
        return entry
