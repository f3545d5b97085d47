"""Operator sign-in on the operator page, in a real browser (Debian's chromium).

A station whose operators are listed with hashed PINs and badges and which requires sign-in:
the page asks for it on load, a badge scan (scanner types + Enter) or name and PIN signs in,
then scan + Start runs with that operator recorded. A page of another site cannot start.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Page, expect  # noqa: E402

from station.ui.app import create_app  # noqa: E402
from station.ui.auth import Operator, OperatorBook, hash_badge, hash_pin  # noqa: E402
from station.ui.controller import Controller  # noqa: E402
from station.ui.history import History  # noqa: E402
from station.ui.hub import Hub  # noqa: E402
from station.ui.requests import Security  # noqa: E402
from station.ui.server import BackgroundServer, serve_in_thread  # noqa: E402
from tests.ui.conftest import _HASH  # noqa: E402
from tests.ui.fake_runner import FakeRunner  # noqa: E402

BADGE = "0004455667"


@dataclass
class Signed:
    runner: FakeRunner
    server: BackgroundServer


@pytest.fixture
def signed(tmp_path: Path) -> Iterator[Signed]:
    runner = FakeRunner(tmp_path / "runs", step_s=0.05)
    controller = Controller(runner, Hub())
    book = OperatorBook(
        (
            Operator("Ana Silva", hash_pin("4711"), hash_badge(BADGE)),
            Operator("Bo", hash_pin("9999")),
        )
    )
    security = Security(engineer_password_hash=_HASH, operators=book, require_operator=True)
    app = create_app(controller, History(tmp_path / "runs"), security=security)
    server = serve_in_thread(app, before_stop=controller.hub.close)
    try:
        yield Signed(runner, server)
    finally:
        runner.close()
        server.stop()


def _scan(page: Page, socket: int, serial: str) -> None:
    field = page.locator(f"#serial-{socket}")
    field.fill(serial)
    field.press("Enter")


def test_badge_sign_in_then_start_records_the_operator(signed: Signed, page: Page) -> None:
    page.goto(signed.server.url)
    expect(page.locator("#signin-dialog")).to_be_visible()  # asked at once: sign-in required
    expect(page.locator("#badge")).to_be_focused()
    page.keyboard.type("1234567")  # an unknown badge
    page.keyboard.press("Enter")
    expect(page.locator("#signin-msg")).to_contain_text("badge not known")
    page.keyboard.type(BADGE)  # the scanner types into the focused field, then Enter
    page.keyboard.press("Enter")
    expect(page.locator("#signin-dialog")).to_be_hidden()
    expect(page.locator("#operator-name")).to_have_text("Ana Silva")
    _scan(page, 1, "SIM-0001")
    page.click("#start-btn")
    expect(page.locator("#socket-1 .verdict")).to_have_text("PASS")
    assert signed.runner.started[-1].operator == "Ana Silva"
    # Sign out: START is disabled with the reason on the page, and the server refuses too.
    page.click("#signin-btn")
    expect(page.locator("#operator-name")).to_have_text("not signed in")
    _scan(page, 1, "SIM-0002")
    expect(page.locator("#start-btn")).to_be_disabled()
    expect(page.locator("#start-reason")).to_contain_text("No operator signed in")
    page.evaluate("start()")  # as a page that ignored the disabled button would
    expect(page.locator("#message")).to_contain_text("no operator signed in")
    assert len(signed.runner.started) == 1


def test_name_and_pin_sign_in_then_start(signed: Signed, page: Page) -> None:
    page.goto(signed.server.url)
    page.fill("#operator-input", "Bo")
    page.fill("#pin", "1111")
    page.press("#pin", "Enter")
    expect(page.locator("#signin-msg")).to_contain_text("wrong PIN")
    page.fill("#operator-input", "Bo")
    page.fill("#pin", "9999")
    page.press("#pin", "Enter")
    expect(page.locator("#operator-name")).to_have_text("Bo")
    _scan(page, 2, "SIM-0003")
    page.click("#start-btn")
    expect(page.locator("#socket-2 .verdict")).to_have_text(re.compile("PASS"))
    assert signed.runner.started[-1].operator == "Bo"


def test_a_page_of_another_site_cannot_start_or_abort(signed: Signed, page: Page) -> None:
    """The attack of the issue: a page elsewhere posting to the station while a part runs."""
    signed.runner.step_s = 0.3
    page.goto(signed.server.url)  # the operator's own screen, signed in, a run going
    expect(page.locator("#badge")).to_be_focused()
    page.keyboard.type(BADGE)
    page.keyboard.press("Enter")
    expect(page.locator("#operator-name")).to_have_text("Ana Silva")
    _scan(page, 1, "SIM-0001")
    page.click("#start-btn")
    expect(page.locator("#abort-btn")).to_be_enabled()
    # Another site's page in the same browser: a form post, then a fetch with credentials.
    evil = page.context.new_page()
    evil.set_content("<p>cheap parts</p>")  # a page that is not the station's (no CSP of ours)
    evil.evaluate(
        """url => { const f = document.createElement("form"); f.method = "POST";
        f.action = url + "/api/abort"; f.enctype = "text/plain"; document.body.appendChild(f);
        window.__answer = fetch(url + "/api/abort", {method: "POST", credentials: "include",
          mode: "no-cors", body: "{}"}).then(() => "sent"); }""",
        signed.server.url,
    )
    assert evil.evaluate("window.__answer") == "sent"
    with evil.expect_response(re.compile(r"/api/abort$")) as answer:
        evil.evaluate("document.forms[0].submit()")
    assert answer.value.status in (401, 403)
    # The run was not aborted: it ends PASS.
    expect(page.locator("#socket-1 .verdict")).to_have_text("PASS", timeout=15_000)
