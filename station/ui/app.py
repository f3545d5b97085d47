"""The web app: routes only. State lives in the controller, history in History.

Pages: `/` operator screen, `/review` review screen. JSON API under `/api`, live updates as
server-sent events on `/api/events`. Errors come back as {"error": message} with the status
code saying whose move it is (409 refused now, 422 bad input, 401 not signed in / no session,
403 role or another site, 421 wrong host, 429 locked out).

Every state-changing request (each POST) needs the session cookie the page gets from
GET /api/session, that session's CSRF token in the X-CSRF-Token header, and an Origin (or
Referer), when the client sends one, of this station itself. See station/ui/guard.py and
station/ui/sessions.py.
"""

from __future__ import annotations

import hmac
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, field_validator
from starlette.exceptions import HTTPException as StarletteHTTPException

from station.errors import UserError
from station.ui.auth import OperatorBook, verify_password
from station.ui.controller import Controller, RunRefusedError, SerialRejectedError
from station.ui.guard import Guard, allowed_hosts, same_origin_problem
from station.ui.history import History, RunFilter
from station.ui.sessions import LoginThrottle, Session, Sessions, TooManySessions

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).parent / "static"
SESSION_COOKIE = "station_session"
# Everything the pages use comes from the station itself (no network on the line): the
# browser is told to refuse anything else.
PAGE_HEADERS = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
}
_ISO_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}([T ][0-9:.]+(Z|[+-]\d{2}:?\d{2})?)?$")


CSRF_HEADER = "x-csrf-token"
MAX_SOCKETS = 64


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StartBody(_Body):
    serials: dict[int, str] = Field(description="socket -> scanned serial", max_length=MAX_SOCKETS)

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


def _error(
    status: int, message: str, headers: dict[str, str] | None = None, **extra: Any
) -> JSONResponse:
    return JSONResponse({"error": message, **extra}, status_code=status, headers=headers)


def create_app(
    controller: Controller,
    history: History,
    *,
    engineer_password_hash: str | None = None,
    security: Security | None = None,
) -> Any:
    """The station's ASGI app: the FastAPI routes inside the Guard (host, body cap, headers)."""
    if security is None:
        security = Security(engineer_password_hash=engineer_password_hash)
    sec = security
    app = FastAPI(title="Gyro calibration station", docs_url=None, redoc_url=None, openapi_url=None)
    sessions = Sessions()
    throttle = LoginThrottle()
    app.state.sessions, app.state.throttle = sessions, throttle

    def is_engineer(request: Request) -> bool:
        session = current(request)
        return session is not None and session.engineer

    @app.exception_handler(Refused)
    async def refused(_: Request, exc: Refused) -> JSONResponse:
        return _error(exc.status, exc.message)

    @app.exception_handler(RequestValidationError)
    async def bad_request(_: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0] if exc.errors() else {}
        parts = [str(p) for p in first.get("loc", ()) if p != "body"]
        where = ".".join(p if p.isprintable() else repr(p) for p in parts)[:200] or "request"
        msg = " ".join(str(first.get("msg", "invalid")).split())[:300]  # one line
        return _error(422, f"bad request: {where}: {msg}; fix the request")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else "request refused"
        if exc.status_code == 400:
            detail = f"bad request: {detail}; send a JSON object"
        return _error(exc.status_code, detail, headers=getattr(exc, "headers", None))

    @app.exception_handler(UserError)
    async def user_error(_: Request, exc: UserError) -> JSONResponse:
        if isinstance(exc, SerialRejectedError):
            return _error(422, str(exc), socket=exc.socket)
        if isinstance(exc, RunRefusedError):
            return _error(409, str(exc))
        return _error(422, str(exc))

    @app.exception_handler(Exception)
    async def internal(_: Request, exc: Exception) -> JSONResponse:
        log.error("internal error in the UI: %s", exc, exc_info=exc)
        return _error(500, "internal error in the station UI; see the station's log")

    # ------------------------------------------------------------------ pages

    @app.get("/", include_in_schema=False)
    async def operator_page() -> FileResponse:
        return FileResponse(STATIC_DIR / "operator.html", headers=PAGE_HEADERS)

    @app.get("/review", include_in_schema=False)
    async def review_page() -> FileResponse:
        return FileResponse(STATIC_DIR / "review.html", headers=PAGE_HEADERS)

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    # ------------------------------------------------------------------ live state

    @app.get("/api/state")
    def state(request: Request) -> dict[str, Any]:
        return {**controller.snapshot(), "role": _role(is_engineer(request))}

    @app.get("/api/events")
    async def events() -> StreamingResponse:
        return StreamingResponse(
            controller.hub.stream(controller.snapshot),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
        )

    # ------------------------------------------------------------------ session, sign-in

    def session_view(session: Session) -> dict[str, Any]:
        return {
            "role": _role(session.engineer),
            "operator": session.operator,
            "csrf": session.csrf,
            "operators_open": sec.operators.open,
            "operator_required": sec.require_operator,
        }

    def with_cookie(response: Response, session: Session) -> Response:
        response.set_cookie(
            SESSION_COOKIE,
            session.token,
            httponly=True,
            samesite="strict",
            secure=sec.https,
            path="/",
        )
        return response

    @app.get("/api/session")
    def open_session(request: Request) -> Response:
        """The page's session (opened here when it has none) and its CSRF token."""
        session = current(request)
        if session is not None:
            return JSONResponse(session_view(session), headers={"Cache-Control": "no-store"})
        address = _address(request)
        wait_s = throttle.wait_s("addr:" + address)
        if wait_s > 0:
            return _error(429, f"too many failed sign-ins from {address}; wait {wait_s:.0f} s")
        try:
            session = sessions.open(address)
        except TooManySessions:
            return _error(429, f"too many new sessions from {address}; wait a minute")
        response = JSONResponse(session_view(session), headers={"Cache-Control": "no-store"})
        return with_cookie(response, session)

    def locked(session: Session) -> JSONResponse | None:
        wait_s = throttle.wait_s(session.token)
        if wait_s > 0:
            return _error(
                429, f"too many failed sign-ins on this screen; try again in {wait_s:.0f} s"
            )
        return None

    def failed(session: Session, message: str) -> JSONResponse:
        wait_s = throttle.failed_from(session.token, session.address)
        more = f"; wait {wait_s:.0f} s before the next try" if wait_s > 0 else "; try again"
        return _error(401, message + more)

    @app.post("/api/signin")
    def sign_in(body: SignInBody, session: Guarded) -> Response:
        refusal = locked(session)
        if refusal is not None:
            return refusal
        book = sec.operators
        if body.badge is not None:
            if book.open:
                return _error(422, "this station has no badges configured; sign in by name")
            found = book.by_badge(body.badge)
            if found is None:
                return failed(session, "badge not known at this station")
            name = found.name
        elif body.name is not None and book.open:
            name = body.name.strip()
            if not name or not name.isprintable():
                return _error(422, "operator name must be printable text; type your name")
        elif body.name is not None and body.pin is not None:
            found = book.by_pin(body.name, body.pin)
            if found is None:
                return failed(session, "unknown operator or wrong PIN")
            name = found.name
        else:
            return _error(422, "sign in with a badge scan, or your name and PIN")
        throttle.reset(session.token)
        session.operator = name
        fresh = sessions.renew(session)
        log.info("operator %s signed in", name)
        return with_cookie(JSONResponse(session_view(fresh)), fresh)

    @app.post("/api/signout")
    def sign_out(session: Guarded) -> Response:
        session.operator, session.engineer = "", False
        fresh = sessions.renew(session)
        return with_cookie(JSONResponse(session_view(fresh)), fresh)

    # ------------------------------------------------------------------ operator commands

    # Sync handlers run in the thread pool: the event loop stays free to push events.
    @app.post("/api/validate")
    def validate(body: ValidateBody, session: Guarded) -> dict[str, Any]:
        return {
            "socket": body.socket,
            "serial": controller.validate_serial(body.socket, body.serial),
        }

    @app.post("/api/start")
    def start(body: StartBody, session: Guarded) -> Response:
        if sec.require_operator and not session.operator:
            return _error(401, "no operator signed in: scan your badge or sign in to start")
        operator = session.operator or ("engineer" if session.engineer else "")
        run_id = controller.start(body.serials, operator=operator)
        return JSONResponse({"run_id": run_id, "operator": operator})

    @app.post("/api/abort")
    def abort(session: Guarded) -> dict[str, Any]:
        # Any session may abort (a safety action); no operator sign-in needed for it.
        log.info("abort requested by %s", session.operator or "an unsigned session")
        controller.abort()
        return {"aborting": True}

    # ------------------------------------------------------------------ engineer

    @app.get("/api/whoami")
    async def whoami(request: Request) -> dict[str, Any]:
        session = current(request)
        return {
            "role": _role(session is not None and session.engineer),
            "operator": session.operator if session else "",
        }

    @app.post("/api/login")
    def login(body: LoginBody, session: Guarded) -> Response:
        if not sec.engineer_password_hash:
            return _error(
                403,
                "no engineer password is set for this station; run `station ui --hash-password`"
                " and put its output under ui.engineer_password_hash in station.yaml",
            )
        refusal = locked(session)
        if refusal is not None:
            return refusal
        if not verify_password(body.password, sec.engineer_password_hash):
            return failed(session, "wrong engineer password")
        throttle.reset(session.token)
        session.engineer = True
        fresh = sessions.renew(session)
        return with_cookie(JSONResponse(session_view(fresh)), fresh)

    @app.post("/api/logout")
    def logout(session: Guarded) -> Response:
        session.engineer = False
        fresh = sessions.renew(session)
        return with_cookie(JSONResponse(session_view(fresh)), fresh)

    @app.get("/api/choices")
    def choices(request: Request) -> Response:
        if not is_engineer(request):
            return _error(403, "procedure selection needs the engineer role; log in as engineer")
        return JSONResponse(
            {
                "procedures": [vars(p) for p in controller.runner.procedures()],
                "products": [vars(p) for p in controller.runner.products()],
                "selection": controller.snapshot()["selection"],
            }
        )

    @app.post("/api/select")
    def select(body: SelectBody, session: Guarded) -> Response:
        if not session.engineer:
            return _error(403, "procedure selection needs the engineer role; log in as engineer")
        controller.select(body.procedure, body.product)
        return JSONResponse({"selection": controller.snapshot()["selection"]})

    # ------------------------------------------------------------------ review

    @app.get("/api/runs")
    def runs(
        serial: str = "",
        verdict: str = "",
        product: str = "",
        operator: str = "",
        since: str = "",
        until: str = "",
        limit: int = 500,
    ) -> dict[str, Any]:
        if verdict and verdict.upper() not in {"PASS", "FAIL", "ERROR", "ABORTED"}:
            raise UserError(f"verdict {verdict!r} unknown; use PASS, FAIL, ERROR or ABORTED")
        for name, value in (("since", since), ("until", until)):
            if value and not _ISO_DATE.match(value):
                raise UserError(f"{name} {value!r} is not a date; use YYYY-MM-DD")
        flt = RunFilter(serial, verdict, product, operator, since, until)
        summary, rows = history.query(flt, limit=max(1, min(limit, 5000)))
        return {"summary": summary, "runs": rows}

    @app.get("/runs/{key}/certificate.pdf")
    async def certificate(key: str) -> Response:
        folder = controller.run_folders.get(key) or history.folder(key)
        if folder is None or not (folder / "certificate.pdf").is_file():
            return _error(404, f"no certificate for run {key}; it may have ended in an error")
        return FileResponse(
            folder / "certificate.pdf",
            media_type="application/pdf",
            headers={"Content-Disposition": f'inline; filename="{key}.pdf"'},
        )

    return Guard(app, sec.hosts)


def current(request: Request) -> Session | None:
    """The request's session, None without a valid cookie."""
    sessions: Sessions = request.app.state.sessions
    return sessions.get(request.cookies.get(SESSION_COOKIE))


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


def _address(request: Request) -> str:
    return request.client.host if request.client is not None else "unknown"


def _role(engineer: bool) -> str:
    return "engineer" if engineer else "operator"
