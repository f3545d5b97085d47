"""Sign-in routes: the page's session, operator sign-in and sign-out, engineer login.

Operators sign in by badge scan or name and PIN (station.yaml ui.operators; on an open
station, with no operators listed, by name only). Failures are throttled per client
(station/ui/sessions.py). Every change of who is signed in issues new tokens.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response

from station.ui.auth import verify_password
from station.ui.requests import (
    Guarded,
    LoginBody,
    Security,
    SignInBody,
    client_address,
    current,
    error,
    role,
)
from station.ui.requests import with_cookie as set_cookie
from station.ui.sessions import LoginThrottle, Session, Sessions, TooManySessions

log = logging.getLogger(__name__)


def open_new_session(
    request: Request, sessions: Sessions, throttle: LoginThrottle
) -> Session | JSONResponse:
    """A new session for the request's client, or the 429 refusing it (a flood)."""
    address = client_address(request)
    try:
        session = sessions.open(address)
    except TooManySessions:
        return error(429, f"too many new sessions from {address}; wait a minute")
    # an address under a sign-in lockout still gets a session (a reloaded screen must be
    # able to ABORT), but it starts locked for signing in: no fresh guesses
    throttle.inherit(session.token, "addr:" + address)
    return session


def session_reply(
    request: Request,
    sessions: Sessions,
    throttle: LoginThrottle,
    view: Callable[[Session], dict[str, Any]],
    cookie: Callable[[Response, Session], Response],
) -> Response:
    """`GET /api/session` of a screen (the operator's, the line's): the request's session as
    `view` shows it, opened here with its `cookie` when the request has none."""
    session = current(request)
    if session is not None:
        return JSONResponse(view(session), headers={"Cache-Control": "no-store"})
    opened = open_new_session(request, sessions, throttle)
    if isinstance(opened, JSONResponse):
        return opened
    return cookie(JSONResponse(view(opened), headers={"Cache-Control": "no-store"}), opened)


def lockout(throttle: LoginThrottle, session: Session) -> JSONResponse | None:
    """The 429 while this client must wait before its next sign-in try; None when it may."""
    wait_s = throttle.wait_s(session.token)
    if wait_s > 0:
        return error(429, f"too many failed sign-ins on this screen; try again in {wait_s:.0f} s")
    return None


def count_failure(throttle: LoginThrottle, session: Session, message: str) -> JSONResponse:
    """A failed sign-in counted (client and address) and its 401, saying any wait imposed."""
    wait_s = throttle.failed_from(session.token, session.address)
    more = f"; wait {wait_s:.0f} s before the next try" if wait_s > 0 else "; try again"
    return error(401, message + more)


class _SignInDesk:
    """What the sign-in routes share: the station's security settings, its sessions and the
    sign-in throttle."""

    def __init__(self, app: FastAPI, sec: Security) -> None:
        self.sec = sec
        self.sessions: Sessions = app.state.sessions
        self.throttle: LoginThrottle = app.state.throttle

    def view(self, session: Session) -> dict[str, Any]:
        sec = self.sec
        return {
            "role": role(session.engineer),
            "operator": session.operator,
            "csrf": session.csrf,
            "operators_open": sec.operators.open,
            "operator_required": sec.require_operator,
            "quality": session.quality,
            "engineer_login": bool(sec.engineer_password_hash),
        }

    def with_cookie(self, response: Response, session: Session) -> Response:
        return set_cookie(response, session, secure=self.sec.https)

    def renewed(self, session: Session) -> Response:
        """The session under new tokens (who is signed in changed) and its view."""
        fresh = self.sessions.renew(session)
        return self.with_cookie(JSONResponse(self.view(fresh)), fresh)

    def operator(self, body: SignInBody, session: Session) -> tuple[str, bool] | JSONResponse:
        """(name, quality role) of the operator the body signs in, or the refusal."""
        book = self.sec.operators
        if body.badge is not None:
            if book.open:
                return error(422, "this station has no badges configured; sign in by name")
            found = book.by_badge(body.badge)
            if found is None:
                return count_failure(self.throttle, session, "badge not known at this station")
            return found.name, found.role == "quality"
        if body.name is not None and book.open:
            name = body.name.strip()
            if not name or not name.isprintable():
                return error(422, "operator name must be printable text; type your name")
            return name, False
        if body.name is not None and body.pin is not None:
            found = book.by_pin(body.name, body.pin)
            if found is None:
                return count_failure(self.throttle, session, "unknown operator or wrong PIN")
            return found.name, found.role == "quality"
        return error(422, "sign in with a badge scan, or your name and PIN")


def add_sign_in_routes(app: FastAPI, sec: Security) -> None:
    desk = _SignInDesk(app, sec)
    _add_session_routes(app, desk)
    _add_operator_routes(app, desk)
    _add_engineer_routes(app, desk)


def _add_session_routes(app: FastAPI, desk: _SignInDesk) -> None:
    @app.get("/api/session")
    def open_session(request: Request) -> Response:
        """The page's session (opened here when it has none) and its CSRF token."""
        return session_reply(request, desk.sessions, desk.throttle, desk.view, desk.with_cookie)

    @app.get("/api/whoami")
    async def whoami(request: Request) -> dict[str, Any]:
        session = current(request)
        return {
            "role": role(session is not None and session.engineer),
            "operator": session.operator if session else "",
        }


def _add_operator_routes(app: FastAPI, desk: _SignInDesk) -> None:
    @app.post("/api/signin")
    def sign_in(body: SignInBody, session: Guarded) -> Response:
        refusal = lockout(desk.throttle, session)
        if refusal is not None:
            return refusal
        who = desk.operator(body, session)
        if isinstance(who, JSONResponse):
            return who
        desk.throttle.reset(session.token)
        session.operator, session.quality = who
        log.info("operator %s signed in", who[0])
        return desk.renewed(session)

    @app.post("/api/signout")
    def sign_out(session: Guarded) -> Response:
        session.operator, session.engineer, session.quality = "", False, False
        return desk.renewed(session)


def _add_engineer_routes(app: FastAPI, desk: _SignInDesk) -> None:
    @app.post("/api/login")
    def login(body: LoginBody, session: Guarded) -> Response:
        password_hash = desk.sec.engineer_password_hash
        if not password_hash:
            return error(
                403,
                "no engineer password is set for this station; run `station ui --hash-password`"
                " and put its output under ui.engineer_password_hash in station.yaml",
            )
        refusal = lockout(desk.throttle, session)
        if refusal is not None:
            return refusal
        if not verify_password(body.password, password_hash):
            return count_failure(desk.throttle, session, "wrong engineer password")
        desk.throttle.reset(session.token)
        session.engineer = True
        return desk.renewed(session)

    @app.post("/api/logout")
    def logout(session: Guarded) -> Response:
        session.engineer = False
        return desk.renewed(session)
