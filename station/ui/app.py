"""The web app: routes only. State lives in the controller, history in History.

Pages: `/` operator screen, `/review` review screen. JSON API under `/api`, live updates as
server-sent events on `/api/events`. Errors come back as {"error": message} with the status
code saying whose move it is (409 refused now, 422 bad input, 401/403 role).
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
from pydantic import BaseModel, Field

from station.errors import UserError
from station.ui.auth import LoginThrottle, Sessions, verify_password
from station.ui.controller import Controller, RunRefusedError, SerialRejectedError
from station.ui.history import History, RunFilter

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


class StartBody(BaseModel):
    serials: dict[int, str] = Field(description="socket -> scanned serial")
    operator: str = Field(default="", max_length=64)


class ValidateBody(BaseModel):
    socket: int
    serial: str = Field(max_length=256)


class LoginBody(BaseModel):
    password: str = Field(max_length=256)


class SelectBody(BaseModel):
    procedure: str | None = None
    product: str | None = None


def _error(status: int, message: str, **extra: Any) -> JSONResponse:
    return JSONResponse({"error": message, **extra}, status_code=status)


def create_app(
    controller: Controller,
    history: History,
    *,
    engineer_password_hash: str | None,
) -> FastAPI:
    app = FastAPI(title="Gyro calibration station", docs_url=None, redoc_url=None)
    sessions = Sessions()
    throttle = LoginThrottle()

    def is_engineer(request: Request) -> bool:
        return sessions.is_engineer(request.cookies.get(SESSION_COOKIE))

    @app.exception_handler(RequestValidationError)
    async def bad_request(_: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ()) if p != "body") or "request"
        return _error(422, f"bad request: {where}: {first.get('msg', 'invalid')}; fix the request")

    @app.exception_handler(UserError)
    async def user_error(_: Request, exc: UserError) -> JSONResponse:
        if isinstance(exc, SerialRejectedError):
            return _error(422, str(exc), socket=exc.socket)
        if isinstance(exc, RunRefusedError):
            return _error(409, str(exc))
        return _error(422, str(exc))

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

    # ------------------------------------------------------------------ operator commands

    # Sync handlers run in the thread pool: the event loop stays free to push events.
    @app.post("/api/validate")
    def validate(body: ValidateBody) -> dict[str, Any]:
        return {
            "socket": body.socket,
            "serial": controller.validate_serial(body.socket, body.serial),
        }

    @app.post("/api/start")
    def start(body: StartBody) -> dict[str, Any]:
        run_id = controller.start(body.serials, operator=body.operator.strip())
        return {"run_id": run_id}

    @app.post("/api/abort")
    def abort() -> dict[str, Any]:
        controller.abort()
        return {"aborting": True}

    # ------------------------------------------------------------------ engineer

    @app.get("/api/whoami")
    async def whoami(request: Request) -> dict[str, Any]:
        return {"role": _role(is_engineer(request))}

    @app.post("/api/login")
    def login(body: LoginBody) -> Response:
        if not engineer_password_hash:
            return _error(
                403,
                "no engineer password is set for this station; run `station ui --hash-password`"
                " and put its output under ui.engineer_password_hash in station.yaml",
            )
        wait_s = throttle.wait_s()
        if wait_s > 0:
            return _error(429, f"too many wrong passwords; try again in {wait_s:.0f} s")
        if not verify_password(body.password, engineer_password_hash):
            throttle.failed()
            return _error(401, "wrong engineer password; try again")
        throttle.reset()
        response = JSONResponse({"role": "engineer"})
        response.set_cookie(
            SESSION_COOKIE, sessions.open(), httponly=True, samesite="strict", max_age=8 * 3600
        )
        return response

    @app.post("/api/logout")
    async def logout(request: Request) -> Response:
        sessions.close(request.cookies.get(SESSION_COOKIE))
        response = JSONResponse({"role": "operator"})
        response.delete_cookie(SESSION_COOKIE)
        return response

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
    def select(request: Request, body: SelectBody) -> Response:
        if not is_engineer(request):
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

    return app


def _role(engineer: bool) -> str:
    return "engineer" if engineer else "operator"
