"""Review-screen routes for tamper evidence and approvals.

    GET  /api/runs/{key}/integrity   verification result and approvals of one run
    POST /api/runs/{key}/approve     a quality approval (signed-in operator with role quality)

The approval itself is station/approvals.py: second PAdES signature, approvals.json, new
manifest. It is signed with the station's key, named in station.yaml (Security.settings).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel

from station.errors import UserError
from station.ui.controller import Controller
from station.ui.history import History
from station.ui.requests import Guarded, Security, error

log = logging.getLogger(__name__)


class ApproveBody(BaseModel):
    remark: str = ""  # why it is approved; needed unless the run PASSed (station/approvals.py)


def add_approval_routes(app: FastAPI, controller: Controller, history: History,
                        sec: Security) -> None:
    def folder_of(key: str) -> Path | None:
        return controller.run_folders.get(key) or history.folder(key)

    def trusted() -> set[str] | None:
        # signing (pyhanko, cryptography): loaded only when used
        from station.certify import trusted_fingerprints

        return trusted_fingerprints(sec.settings) if sec.settings is not None else None

    @app.get("/api/runs/{key}/integrity")
    def integrity(key: str) -> Response:
        # signing (pyhanko, cryptography): loaded only when used
        from station.approvals import read_approvals
        from station.manifest import verify_folder

        folder = folder_of(key)
        if folder is None:
            return error(404, f"no run {key} at this station")
        result = verify_folder(folder, trusted())
        try:
            approvals: list[dict[str, Any]] = read_approvals(folder)
        except UserError as exc:
            approvals = []
            result.problems.append(str(exc))
        return JSONResponse({"status": result.status.name.lower(), "problems": result.problems,
                             "altered_files": result.altered_files, "approvals": approvals})

    @app.post("/api/runs/{key}/approve")
    def approve_run(key: str, session: Guarded, body: ApproveBody | None = None) -> Response:
        # signing (pyhanko, cryptography): loaded only when used
        from station.approvals import approve

        if not session.quality or not session.operator:
            return error(403, "approving a run needs the quality role; sign in as a quality "
                              "engineer (station.yaml ui.operators role: quality)")
        if sec.settings is None:
            return error(503, "this station has no signing settings; start it with "
                              "`station ui` from a station file")
        folder = folder_of(key)
        if folder is None:
            return error(404, f"no run {key} at this station")
        entry = approve(folder, sec.settings, by=session.operator, role="quality",
                        remark=body.remark if body else "")
        log.info("run %s approved by %s", key, session.operator)
        return JSONResponse({"approved": entry})
