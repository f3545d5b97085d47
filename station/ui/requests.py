"""What a request to the station UI must carry, and the shapes of the API's bodies.

A state-changing request (each POST) needs the session cookie the page gets from
GET /api/session, that session's CSRF token in the X-CSRF-Token header, and an Origin (or
Referer), when the client sends one, of this station itself (`guarded`). Bodies are strict
pydantic models: unknown fields, oversize strings and out-of-range sockets are refused (422).
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Depends, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field, field_validator

from station.ui.auth import OperatorBook
from station.ui.guard import allowed_hosts, same_origin_problem
from station.ui.sessions import Session, Sessions

SESSION_COOKIE = "station_session"
CSRF_HEADER = "x-csrf-token"
MAX_SOCKETS = 64


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StartBody(_Body):
    serials: dict[int, str] = Field(description="socket -> scanned serial", max_length=MAX_SOCKETS)
    work_order: str = Field("", max_length=64, description="work order the parts belong to")
    lot: str = Field("", max_length=64, description="lot the parts belong to")

    @field_validator("serials")
    @classmethod
    def _bounded(cls, value: dict[int, str]) -> dict[int, str]:
        for socket, serial in value.items():
            if not 1 <= socket <= MAX_SOCKETS:
                raise ValueError(f"socket {socket} is not 1..{MAX_SOCKETS}")
            if len(serial) > 256:
                raise ValueError(f"socket {socket}: serial longer than 256 characters")
        return value


class ValidateBody(_Body):
    socket: int = Field(ge=1, le=MAX_SOCKETS)
    serial: str = Field(max_length=256)


class LoginBody(_Body):
    password: str = Field(max_length=256)


class SignInBody(_Body):
    badge: str | None = Field(None, min_length=1, max_length=128)
    name: str | None = Field(None, min_length=1, max_length=64)
    pin: str | None = Field(None, min_length=1, max_length=64)


class SelectBody(_Body):
    procedure: str | None = Field(None, max_length=4096)
    product: str | None = Field(None, max_length=4096)


class Refused(Exception):
    """A request refused before its handler ran (no session, bad token, another site)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass(frozen=True)
class Security:
    """How the app admits requests; built from station.yaml's ui section by launch.py."""

    engineer_password_hash: str | None = None
    operators: OperatorBook = OperatorBook()
    require_operator: bool = False
    hosts: frozenset[str] = frozenset(allowed_hosts("127.0.0.1"))
    https: bool = False
    settings: Any = None  # station.settings.LoadedSettings: its key signs approvals
    language: str | None = None  # the screen's language (station.yaml ui.language); None: browser's


def error(
    status: int, message: str, headers: dict[str, str] | None = None, **extra: Any
) -> JSONResponse:
    return JSONResponse({"error": message, **extra}, status_code=status, headers=headers)


def cookie_name(request: Request) -> str:
    """The app's session cookie: the station's, or another app's own (the line dashboard's,
    so that two apps on one host, whose cookies ignore the port, keep their sessions apart)."""
    return str(getattr(request.app.state, "session_cookie", SESSION_COOKIE))


def current(request: Request) -> Session | None:
    """The request's session, None without a valid cookie."""
    sessions: Sessions = request.app.state.sessions
    return sessions.get(request.cookies.get(cookie_name(request)))


def with_cookie(
    response: Response, session: Session, *, secure: bool, name: str = SESSION_COOKIE
) -> Response:
    """`response` setting the session cookie: HttpOnly, SameSite=Strict, Secure over HTTPS."""
    response.set_cookie(name, session.token, httponly=True, samesite="strict", secure=secure,
                        path="/")
    return response


def guarded(request: Request) -> Session:
    """The session of a state-changing request; Refused when it has none or is forged."""
    problem = same_origin_problem(
        {k.lower(): v for k, v in request.headers.items()}, request.url.scheme
    )
    if problem:
        raise Refused(403, problem + "; use the station's own screen")
    session = current(request)
    if session is None:
        raise Refused(401, "no session: open the station's screen (GET /api/session) and sign in")
    token = request.headers.get(CSRF_HEADER, "")
    if not token or not hmac.compare_digest(token.encode(), session.csrf.encode()):
        raise Refused(403, "missing or wrong X-CSRF-Token; reload the station's screen")
    return session


Guarded = Annotated[Session, Depends(guarded)]


def client_address(request: Request) -> str:
    return request.client.host if request.client is not None else "unknown"


def role(engineer: bool) -> str:
    return "engineer" if engineer else "operator"
