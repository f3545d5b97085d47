"""The line dashboard's sign-in in chromium: nothing shown before it, each role's panels
after it, and a page of another site that cannot read the API nor sign anybody out."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.responses import HTMLResponse

from station.db.connect import dispose_all
from station.results_db import ResultsDB
from station.ui.headless import wait_js
from station.ui.server import serve_in_thread
from tests.linedb.linekit import LINE_NAMES, line_app, line_runs, sign_in_page


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    folder: Path = tmp_path_factory.mktemp("signin-page")
    runs = line_runs(30, ["EOL-A", "EOL-B"], seed=3, root=folder / "runs")
    db = ResultsDB(folder / "line.sqlite")
    db.add_records([(r.folder, r.record) for r in runs])
    server = serve_in_thread(line_app(db.engine))
    try:
        yield server.url
    finally:
        server.stop()
        dispose_all()


@pytest.fixture(scope="module")
def other_site() -> Iterator[str]:
    """A page of another site (127.0.0.2: another host, so another origin and site)."""
    app = FastAPI()

    @app.get("/")
    def page() -> HTMLResponse:
        return HTMLResponse("<!doctype html><title>elsewhere</title><p>elsewhere</p>")

    server = serve_in_thread(app, host="127.0.0.2")
    try:
        yield server.url
    finally:
        server.stop()


def test_signed_out_page_shows_the_form_and_no_data(line: str, page: Any) -> None:
    page.goto(line)
    wait_js(page, "!document.getElementById('signin').hidden")
    assert page.locator("#dashboard").is_hidden() and page.locator("#top").is_hidden()
    assert page.evaluate("document.querySelectorAll('#stations .card, #runs tbody tr').length") == 0
    assert page.evaluate("document.body.dataset.loaded") is None
    page.fill("#signin input[name=name]", LINE_NAMES["viewer"])
    page.fill("#signin input[name=password]", "not-the-password")
    page.click("#signin button[type=submit]")
    said = wait_js(page, "document.getElementById('signin-error').textContent")
    assert "wrong password" in said and page.locator("#dashboard").is_hidden()


def test_viewer_sees_yields_but_no_capability_nor_certificates(line: str, page: Any) -> None:
    sign_in_page(page, line, "viewer")
    assert page.locator("#dashboard").is_visible()
    assert "units" in page.locator("#yield-all").inner_text()
    assert page.locator("#runs tbody tr").count() > 0
    assert page.locator("#runs a[href^='/certificate/']").count() == 0
    assert page.locator("section[data-needs=quality]").is_hidden()
    assert page.locator("label[data-needs=engineer]").is_hidden()
    assert "Vera Viewer (viewer)" in page.locator("#who").inner_text()


def test_quality_sees_capability_and_certificates_and_signs_out(line: str, page: Any) -> None:
    sign_in_page(page, line, "quality")
    assert page.locator("section[data-needs=quality]").is_visible()
    assert page.locator("#capability tbody tr").count() > 0
    assert page.locator("#runs a[href^='/certificate/']").count() > 0
    assert page.locator("label[data-needs=engineer]").is_hidden()
    with page.expect_navigation():  # sign-out reloads the page: no data left in it
        page.click("#signout")
    wait_js(page, "!document.getElementById('signin').hidden")
    assert page.evaluate("fetch('/api/yields').then(r => r.status)") == 401


def test_another_site_cannot_read_the_api_nor_sign_out(line: str, other_site: str,
                                                       page: Any) -> None:
    sign_in_page(page, line, "engineer")
    assert page.evaluate("fetch('/api/yields').then(r => r.status)") == 200
    evil = page.context.new_page()
    evil.goto(other_site)
    target = line + "/api/yields"
    read = evil.evaluate(
        "u => fetch(u, {credentials: 'include'}).then(r => 'read ' + r.status, e => 'failed')",
        target)
    assert read == "failed"  # no Access-Control-Allow-Origin: the browser withholds it
    opaque = evil.evaluate(
        "u => fetch(u, {mode: 'no-cors', credentials: 'include'})"
        ".then(r => r.type + ' ' + r.status)", target)
    assert opaque == "opaque 0"  # nothing of the answer reaches the other site
    evil.evaluate("u => fetch(u, {method: 'POST', mode: 'no-cors', credentials: 'include'})"
                  ".then(() => 'sent', () => 'failed')", line + "/api/signout")
    # the forged sign-out did nothing: the dashboard's own page still reads as the engineer
    assert page.evaluate("fetch('/api/session').then(r => r.json()).then(s => s.role)") == \
        "engineer"
    assert page.evaluate("fetch('/api/yields').then(r => r.status)") == 200
