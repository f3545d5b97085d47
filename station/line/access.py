"""Sign-in on the line dashboard, and the role each request needs.

The operator screen's rules, with its own pieces (station/ui/): a session in an HttpOnly,
SameSite=Strict cookie (Secure over HTTPS) with a CSRF token the page sends back in
X-CSRF-Token on each POST, Origin checked on each POST, new tokens at each sign-in and
sign-out, failed sign-ins throttled per client and per address (LoginThrottle), the Host
header checked before any route (Guard, in station/line/app.py).

`GET /api/session` opens the page's session and says who is signed in (role "" when nobody);
`POST /api/signin` {name, password}; `POST /api/signout`. Every other `/api/*` and
`/certificate/*` needs a signed-in user of the role it names (`needs`): 401 without one,
403 for a role below it. The role rides on the operator screen's Session: `operator` holds
the user's name, `quality` and `engineer` the role.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from station.line.users import LineUsers, may
from station.ui.guard import allowed_hosts
from station.ui.requests import Guarded, Refused, current, with_cookie
from station.ui.sessions import LoginThrottle, Session, Sessions
from station.ui.signin import count_failure, lockout, session_reply

log = logging.getLogger(__name__)

LINE_COOKIE = "line_session"


@dataclass(frozen=True)
class LineAccess:
    """Who may sign in, the host names answered, and whether the page is served over HTTPS."""

    users: LineUsers = LineUsers()
    hosts: frozenset[str] = frozenset(allowed_hosts("127.0.0.1"))
    https: bool = False


class SignInBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=256)


def role_of(session: Session | None) -> str:
    if session is None or not session.operator:
        return ""
    return "engineer" if session.engineer else "quality" if session.quality else "viewer"


def needs(role: str) -> Callable[[Request], Session]:
    """A dependency: the request's session when its user is `role` or above; Refused (401
    signed out, 403 a lower role) otherwise. Simulated runs are for engineers only."""

    def check(request: Request) -> Session:
        session = current(request)
        have = role_of(session)
        if not have:
            raise Refused(401, "sign in on the line dashboard first")
        wanted = "engineer" if request.query_params.get("simulated") == "include" else role
        if not may(have, wanted):
            raise Refused(403, f"this needs the {wanted} role; {have} is signed in")
        assert session is not None
        return session

    return check


def add_line_sign_in(app: FastAPI, access: LineAccess) -> None:
    sessions, throttle = Sessions(), LoginThrottle()
    app.state.sessions, app.state.throttle = sessions, throttle
    app.state.session_cookie = LINE_COOKIE

    def view(session: Session) -> dict[str, Any]:
        return {"role": role_of(session), "user": session.operator, "csrf": session.csrf}

    def cookie(response: Response, session: Session) -> Response:
        return with_cookie(response, session, secure=access.https, name=LINE_COOKIE)

    def answer(session: Session) -> Response:
        return cookie(JSONResponse(view(session), headers={"Cache-Control": "no-store"}), session)

    @app.get("/api/session")
    def open_session(request: Request) -> Response:
        return session_reply(request, sessions, throttle, view, cookie)

    @app.post("/api/signin")
    def sign_in(body: SignInBody, session: Guarded) -> Response:
        refusal = lockout(throttle, session)
        if refusal is not None:
            return refusal
        user = access.users.check(body.name, body.password)
        if user is None:
            return count_failure(throttle, session, "unknown user or wrong password")
        throttle.reset(session.token)
        session.operator = user.name
        session.quality, session.engineer = user.role == "quality", user.role == "engineer"
        log.info("%s signed in on the line dashboard as %s", user.name, user.role)
        return answer(sessions.renew(session))

    @app.post("/api/signout")
    def sign_out(session: Guarded) -> Response:
        session.operator, session.engineer, session.quality = "", False, False
        return answer(sessions.renew(session))
