"""The line's dashboard web app: read-only, over the line's central database.

Pages: `/` the dashboard. JSON under `/api`: `stations` (with the filter choices), `yields`,
`capability`, `chart` (a coefficient's control chart), `runs` (latest runs, a page of 50;
`?before=` the last one's started_utc for the next page). Every panel
leaves simulated runs (`runs.simulated`) out unless asked with `?simulated=include`.
`/certificate/{run_id}` serves the run's certificate from the run folder the station
recorded, when this computer can reach it (from inside its archive once `station archive`
packed it: station/line/archived.py).
Errors come back as {"error": message} (422 bad input, 404 not found, 503 database down).
Everything but the page itself needs a signed-in user of the right role (401 signed out,
403 a role below it: station/line/access.py, station/line/users.py); the Host header is
checked before any route (station/ui/guard.py).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from sqlalchemy.engine import Engine
from sqlalchemy.exc import SQLAlchemyError

from procedures.runtime.record import CERTIFICATE_FILE
from station.db.schema import CAL_KEYS
from station.db.yields import DEFAULT_SHIFT_STARTS_H
from station.line import queries
from station.line.access import LineAccess, add_line_sign_in, needs
from station.line.archived import archived_certificate
from station.line.queries import Filters
from station.results_db import ResultsDBError, parse_since
from station.run_archive import split_ref
from station.ui.guard import Guard
from station.ui.requests import Refused

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).parent / "static"
PAGE_HEADERS = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
}
_RUN_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.:+\-]{0,160}$")
_TEXT = re.compile(r"^[^\x00-\x1f]{0,200}$")
_SIMULATED = {"": False, "exclude": False, "include": True}


@dataclass(frozen=True)
class LineOptions:
    offline_after_s: float = 60.0
    shift_starts_h: tuple[int, ...] = DEFAULT_SHIFT_STARTS_H
    confidence: float = 0.95
    chart_points: int = 200


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def _filters(request: Request) -> Filters:
    q = request.query_params
    values = {k: (q.get(k) or "").strip() or None
              for k in ("since", "until", "product", "station", "lot")}
    for k, v in values.items():
        if v is not None and not _TEXT.match(v):
            raise ValueError(f"{k}: at most 200 printable characters")
    for k in ("since", "until"):
        given = values[k]
        if given:
            parse_since(given)  # says what it wants when not a date
    return Filters(**values, include_simulated=_include_simulated(q.get("simulated")))


def _include_simulated(given: str | None) -> bool:
    choice = (given or "").strip()
    if choice not in _SIMULATED:
        raise ValueError("simulated: choose include or exclude (the default)")
    return _SIMULATED[choice]


Answer = Callable[[Callable[[Any], Any], Request], Any]
_VIEWER, _QUALITY = [Depends(needs("viewer"))], [Depends(needs("quality"))]


def create_line_app(
    engine: Engine, options: LineOptions | None = None, access: LineAccess | None = None
) -> Guard:
    """The dashboard inside the Guard; without `access` nobody can sign in."""
    opts = options or LineOptions()
    rules = access or LineAccess()
    app = FastAPI(title="gyrocal line", docs_url=None, redoc_url=None, openapi_url=None)
    add_line_sign_in(app, rules)

    @app.exception_handler(Refused)
    async def refused(_: Request, exc: Refused) -> JSONResponse:
        return _error(exc.status, exc.message)

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(STATIC_DIR / "line.html", headers=PAGE_HEADERS)

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    _add_panels(app, _answerer(engine), opts)
    _add_certificate(app, engine)

    @app.api_route("/api/{rest:path}", methods=["GET", "POST"], dependencies=_VIEWER)
    def unknown(rest: str) -> Response:  # signed out, an unknown path says no more than 401
        return _error(404, f"no such request: /api/{rest[:100]}")

    return Guard(app, rules.hosts)


def _answerer(engine: Engine) -> Answer:
    """A panel's answer: its filters read, its queries run on a connection of its own, bad
    input 422 and the database down 503, both as {"error": message}."""
    def answer(make: Callable[[Any], Any], request: Request) -> Any:
        try:
            flt = _filters(request)
            t0 = time.perf_counter()
            with engine.connect() as con:
                body = make((con, flt))
            log.debug("%s in %.3f s", request.url.path, time.perf_counter() - t0)
            return body
        except (ValueError, ResultsDBError) as exc:
            return _error(422, str(exc))
        except SQLAlchemyError as exc:
            return _error(503, f"the line database is not reachable ({exc.__class__.__name__}); "
                               "check the database server")
    return answer


def _add_panels(app: FastAPI, answer: Answer, opts: LineOptions) -> None:
    """One request per panel: the page asks for them at once and the server answers them in
    parallel (each on its own connection), so the page waits for the slowest, not the sum."""
    @app.get("/api/stations", dependencies=_VIEWER)
    def station_list(request: Request) -> Any:
        return answer(lambda a: {"stations": queries.station_states(
                                     a[0], opts.offline_after_s,
                                     include_simulated=a[1].include_simulated),
                                 "simulated_left_out": queries.simulated_left_out(a[0], a[1]),
                                 "choices": queries.choices(a[0], a[1]),
                                 "coefficients": list(CAL_KEYS)}, request)

    @app.get("/api/yields", dependencies=_VIEWER)
    def yields(request: Request) -> Any:
        return answer(lambda a: queries.yield_tables(a[0], a[1], opts.shift_starts_h), request)

    @app.get("/api/capability", dependencies=_QUALITY)
    def capability(request: Request) -> Any:
        return answer(lambda a: {
            "capability": queries.capabilities(a[0], a[1], opts.confidence),
            "cpk_interval": f"Bissell's approximation, {opts.confidence:.0%} two-sided",
            "window": queries.CPK_WINDOW,
        }, request)

    @app.get("/api/chart", dependencies=_VIEWER)
    def chart(request: Request, coefficient: str = "bias_dps") -> Any:
        return answer(lambda a: queries.control_chart(a[0], a[1], coefficient,
                                                      opts.chart_points), request)

    @app.get("/api/runs", dependencies=_VIEWER)
    def latest(request: Request, before: str | None = None) -> Any:
        return answer(lambda a: {"runs": queries.recent_runs(a[0], a[1], before=before)},
                      request)


def _add_certificate(app: FastAPI, engine: Engine) -> None:
    """/certificate/{run_id}: the PDF from the run folder (or its archive), quality and up."""
    @app.get("/certificate/{run_id}", response_model=None, dependencies=_QUALITY)
    def certificate(run_id: str) -> Response:
        if not _RUN_ID.match(run_id):
            return _error(422, "not a run id")
        try:
            with engine.connect() as con:
                folder = queries.run_folder(con, run_id)
        except SQLAlchemyError:
            return _error(503, "the line database is not reachable; check the database server")
        if folder is None:
            return _error(404, f"run {run_id} is not in the line database")
        if (archived := split_ref(folder)) is not None:  # `station archive` packed it
            return archived_certificate(run_id, *archived)
        pdf = Path(folder) / CERTIFICATE_FILE
        if not pdf.is_file():
            return _error(404, f"the certificate of run {run_id} is not reachable from here: "
                               f"{pdf} (share the station's run folders with this computer "
                               "at the same path)")
        return FileResponse(pdf, media_type="application/pdf",
                            filename=f"{run_id}-{CERTIFICATE_FILE}")
