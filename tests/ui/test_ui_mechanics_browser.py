"""The operator page in a real browser (Debian's chromium), against the fake runner.

These check the page's own mechanics (scan + Enter, Start, live progress, verdict, abort
confirmation, roles, reload mid-run). The same flows against the real engine on the
simulated bench are in test_station_sim.py.
"""

from __future__ import annotations

import re

import pytest

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Page, expect  # noqa: E402

from tests.ui.conftest import ENGINEER_PASSWORD, FakeStation


def _scan(page: Page, socket: int, serial: str) -> None:
    field = page.locator(f"#serial-{socket}")
    field.fill(serial)
    field.press("Enter")


def test_scan_start_progress_pass_and_certificate(fake_station: FakeStation, page: Page) -> None:
    page.goto(fake_station.url)
    _scan(page, 1, "SIM-0001")
    expect(page.locator("#serial-1")).to_have_class(re.compile(r"\bok\b"))
    page.click("#start-btn")
    expect(page.locator("#progress")).to_be_visible()
    expect(page.locator("#step-list li.done").first).to_be_visible()  # progress advanced
    box = page.locator("#socket-1 .verdict-box")
    expect(box.locator(".verdict")).to_have_text("PASS")
    expect(box).to_have_class(re.compile(r"\bPASS\b"))
    href = box.locator("a.certificate").get_attribute("href")
    assert href and href.endswith("/certificate.pdf")
    pdf = page.request.get(fake_station.url + href)
    assert pdf.ok and pdf.body().startswith(b"%PDF")
    # Ready for the next part, last result still shown.
    expect(page.locator("#serial-1")).to_have_value("")
    expect(page.locator("#serial-1")).to_be_focused()
    expect(page.locator("#start-btn")).to_be_enabled()
    ms = page.evaluate("window.__ui.firstProgressMs")
    assert ms is not None and ms > 0


def test_failing_part_shows_fail_and_the_measurement(fake_station: FakeStation, page: Page) -> None:
    page.goto(fake_station.url)
    _scan(page, 2, "BAD-0009")
    page.click("#start-btn")
    box = page.locator("#socket-2 .verdict-box")
    expect(box.locator(".verdict")).to_have_text("FAIL")
    # plain words for the operator, with what to do with the part
    expect(box.locator(".reasons")).to_have_text("Bias too high: 14.2 deg/s, limit +/-10 deg/s")
    expect(box.locator(".disposition")).to_have_text("Red bin: do not ship")
    # the engineering names in the detail view (a tap on the socket)
    page.click("#socket-2 .socket-head")
    expect(page.locator("#detail-dialog")).to_be_visible()
    expect(page.locator("#detail-failed")).to_contain_text("raw_bias_dps: 14.2 deg/s")


def test_bad_serial_refused_on_the_page(fake_station: FakeStation, page: Page) -> None:
    page.goto(fake_station.url)
    _scan(page, 1, "not a serial")
    expect(page.locator("#socket-1 .serial-msg")).to_contain_text("not a GYR-130 serial")
    expect(page.locator("#serial-1")).to_have_class(re.compile(r"\bbad\b"))
    page.click("#start-btn")  # the server refuses it too
    expect(page.locator("#message")).to_contain_text("not a GYR-130 serial")
    assert fake_station.runner.started == []


def test_abort_needs_confirmation_and_ends_aborted(fake_station: FakeStation, page: Page) -> None:
    fake_station.runner.step_s = 0.5
    page.goto(fake_station.url)
    _scan(page, 1, "SIM-0002")
    page.click("#start-btn")
    expect(page.locator("#abort-btn")).to_be_enabled()
    page.click("#abort-btn")
    page.click("#abort-cancel")  # changed their mind: the run goes on
    expect(page.locator("#progress")).to_be_visible()
    page.click("#abort-btn")
    page.click("#abort-confirm")
    expect(page.locator("#socket-1 .verdict")).to_have_text("ABORTED")
    assert fake_station.runner.safe_state_calls == 1


def test_second_start_refused_and_reload_mid_run(fake_station: FakeStation, page: Page) -> None:
    fake_station.runner.step_s = 0.4
    page.goto(fake_station.url)
    _scan(page, 1, "SIM-0003")
    page.click("#start-btn")
    expect(page.locator("#step-name")).not_to_have_text("-")
    csrf = page.evaluate("S.csrf")  # the page's own session: refused because a run is going
    r = page.request.post(
        fake_station.url + "/api/start",
        data={"serials": {"2": "SIM-0004"}},
        headers={"X-CSRF-Token": csrf},
    )
    assert r.status == 409 and "already in progress" in r.json()["error"]
    page.reload()
    expect(page.locator("#progress")).to_be_visible()
    expect(page.locator("#serial-1")).to_have_value("SIM-0003")
    expect(page.locator("#start-btn")).to_be_disabled()
    expect(page.locator("#socket-1 .verdict")).to_have_text("PASS", timeout=15_000)


def test_operator_cannot_reach_selection_engineer_can(
    fake_station: FakeStation, page: Page
) -> None:
    page.goto(fake_station.url)
    expect(page.locator("#procedure-name")).to_have_text("eol-full")
    expect(page.locator("#engineer-panel")).to_be_hidden()
    expect(page.locator("#procedure-select option")).to_have_count(0)
    page.click("#engineer-btn")
    page.fill("#password", "guess")
    page.click("#login-form button[type=submit]")
    expect(page.locator("#login-msg")).to_contain_text("wrong engineer password")
    page.fill("#password", ENGINEER_PASSWORD)
    page.click("#login-form button[type=submit]")
    expect(page.locator("#engineer-panel")).to_be_visible()
    expect(page.locator("#role-badge")).to_have_text("ENGINEER")
    page.select_option("#procedure-select", label="eol-short")
    page.click("#apply-selection")
    expect(page.locator("#procedure-name")).to_have_text("eol-short")
    page.click("#engineer-btn")  # log out
    expect(page.locator("#engineer-panel")).to_be_hidden()


def test_scan_without_focus_lands_in_the_first_empty_socket(
    fake_station: FakeStation, page: Page
) -> None:
    page.goto(fake_station.url)
    expect(page.locator("#serial-1")).to_be_visible()
    page.locator("#procedure-name").click()  # a touch somewhere else: nothing focused
    page.keyboard.type("SIM-0005")
    page.keyboard.press("Enter")
    expect(page.locator("#serial-1")).to_have_value("SIM-0005")
    expect(page.locator("#serial-1")).to_have_class(re.compile(r"\bok\b"))
    page.locator("#procedure-name").click()
    page.keyboard.type("SIM-0006")
    expect(page.locator("#serial-2")).to_have_value("SIM-0006")
