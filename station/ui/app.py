"""The web app: routes only. State lives in the controller, history in History.

Pages: `/` operator screen, `/review` review screen. JSON API under `/api`, live updates as
server-sent events on `/api/events`. Errors come back as {"error": message} with the status
code saying whose move it is (409 refused now, 422 bad input, 401 not signed in / no session,
403 role or another site, 421 wrong host, 429 locked out).

Every state-changing request (each POST) needs a session and its CSRF token
(station/ui/requests.py); sign-in routes are in station/ui/signin.py; the host check, body cap
and security headers around every request in station/ui/guard.py.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from station.errors import UserError
from station.ui import catalog
from station.ui.approval_routes import add_approval_routes
from station.ui.controller import Controller, RunRefusedError, SerialRejectedError
from station.ui.guard import Guard
from station.ui.history import History, RunFilter
from station.ui.requests import (
    Guarded,
    Refused,
    Security,
    SelectBody,
    StartBody,
    ValidateBody,
    current,
    error,
    role,
)
from station.ui.sessions import LoginThrottle, Sessions
from station.ui.signin import add_sign_in_routes

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).parent / "static"
# Everything the pages use comes from the station itself (no network on the line): the
# browser is told to refuse anything else.
PAGE_HEADERS = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
}
_ISO_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}([T ][0-9:.]+(Z|[+-]\d{2}:?\d{2})?)?$")


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
    app.state.sessions, app.state.throttle = Sessions(), LoginThrottle()
    add_sign_in_routes(app, sec)
    add_approval_routes(app, controller, history, sec)
    _add_error_handlers(app)
    _add_pages(app)
    _add_messages(app, sec)
    _add_live_state(app, controller)
    _add_operator_commands(app, controller, sec)
    _add_engineer_routes(app, controller)
    _add_review_routes(app, controller, history)
    return Guard(app, sec.hosts)


def _is_engineer(request: Request) -> bool:
    session = current(request)
    return session is not None and session.engineer


def _add_error_handlers(app: FastAPI) -> None:
    """Every error as {"error": message} with the status saying whose move it is."""

    @app.exception_handler(Refused)
    async def refused(_: Request, exc: Refused) -> JSONResponse:
        return error(exc.status, exc.message)

    @app.exception_handler(RequestValidationError)
    async def bad_request(_: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0] if exc.errors() else {}
        parts = [str(p) for p in first.get("loc", ()) if p != "body"]
        where = ".".join(p if p.isprintable() else repr(p) for p in parts)[:200] or "request"
        msg = " ".join(str(first.get("msg", "invalid")).split())[:300]  # one line
        return error(422, f"bad request: {where}: {msg}; fix the request")

    @app.exception_handler(StarletteHTTPException)
    async def httperror(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else "request refused"
        if exc.status_code == 400:
            detail = f"bad request: {detail}; send a JSON object"
        return error(exc.status_code, detail, headers=getattr(exc, "headers", None))

    @app.exception_handler(UserError)
    async def usererror(_: Request, exc: UserError) -> JSONResponse:
        if isinstance(exc, SerialRejectedError):
            return error(422, str(exc), socket=exc.socket)
        if isinstance(exc, RunRefusedError):
            return error(409, str(exc))
        return error(422, str(exc))

    @app.exception_handler(Exception)
    async def internal(_: Request, exc: Exception) -> JSONResponse:
        log.error("internal error in the UI: %s", exc, exc_info=exc)
        return error(500, "internal error in the station UI; see the station's log")


def _add_pages(app: FastAPI) -> None:
    """The operator and review pages and their static files."""

    @app.get("/", include_in_schema=False)
    async def operator_page() -> FileResponse:
        return FileResponse(STATIC_DIR / "operator.html", headers=PAGE_HEADERS)

    @app.get("/review", include_in_schema=False)
    async def review_page() -> FileResponse:
        return FileResponse(STATIC_DIR / "review.html", headers=PAGE_HEADERS)

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")


def _add_messages(app: FastAPI, sec: Security) -> None:
    @app.get("/api/messages")
    def messages(request: Request, lang: str = "") -> dict[str, Any]:
        """The page's message catalog: station.yaml's language, else the browser's."""
        requested = [t for t in lang[:200].split(",") if t] or catalog.accept_language(
            request.headers.get("accept-language", "")[:500]
        )
        language = catalog.choose(sec.language, requested)
        return {"language": language, "messages": catalog.load(language)}


def _add_live_state(app: FastAPI, controller: Controller) -> None:
    """The state once (GET /api/state) and as server-sent events (/api/events)."""

    @app.get("/api/state")
    def state(request: Request) -> dict[str, Any]:
        return {**controller.snapshot(), "role": role(_is_engineer(request))}

    @app.get("/api/events")
    async def events() -> StreamingResponse:
        return StreamingResponse(
            controller.hub.stream(controller.snapshot),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
        )


def _add_operator_commands(app: FastAPI, controller: Controller, sec: Security) -> None:
    """Validate a serial, start a run, abort it."""

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
            return error(401, "no operator signed in: scan your badge or sign in to start")
        operator = session.operator or ("engineer" if session.engineer else "")
        run_id = controller.start(
            body.serials, operator=operator, work_order=body.work_order.strip(),
            lot=body.lot.strip(),
        )
        return JSONResponse({"run_id": run_id, "operator": operator})

    @app.post("/api/abort")
    def abort(session: Guarded) -> dict[str, Any]:
        # Any session may abort (a safety action); no operator sign-in needed for it.
        log.info("abort requested by %s", session.operator or "an unsigned session")
        controller.abort()
        return {"aborting": True}


def _add_engineer_routes(app: FastAPI, controller: Controller) -> None:
    """The procedure and product choices and the selection (engineer role only)."""

    @app.get("/api/choices")
    def choices(request: Request) -> Response:
        if not _is_engineer(request):
            return error(403, "procedure selection needs the engineer role; log in as engineer")
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
            return error(403, "procedure selection needs the engineer role; log in as engineer")
        controller.select(body.procedure, body.product)
        return JSONResponse({"selection": controller.snapshot()["selection"]})


def _add_review_routes(app: FastAPI, controller: Controller, history: History) -> None:
    """The run history query and the certificates."""

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
            return error(404, f"no certificate for run {key}; it may have ended in an error")
        return FileResponse(
            folder / "certificate.pdf",
            media_type="application/pdf",
            headers={"Content-Disposition": f'inline; filename="{key}.pdf"'},
        )
