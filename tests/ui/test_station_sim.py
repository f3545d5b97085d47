"""Must-show flows in a real browser against the real station on the simulated bench.

The station is the real one, started as on the line: `station ui --sim` in its own process
(station/uut.py engine, drivers, certificates) with the simulated bench as a further process;
the short test procedure at high bench speed keeps each run to seconds. One module-scoped
station serves every test; the bench's own truth is read over its control channel.
"""

from __future__ import annotations

import re
import subprocess

import httpx
import pytest
import yaml

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Page, expect  # noqa: E402

from tests.tools import need
from tests.ui.conftest import ENGINEER_PASSWORD, FAIL_SERIAL, PASS_SERIAL, SimStation

pytestmark = pytest.mark.slow
RUN_TIMEOUT_MS = 90_000


def _verdict(page: Page, socket: int) -> tuple[str, str]:
    """Wait for the socket's verdict; returns it with the reasons shown under it."""
    verdict = page.locator(f"#socket-{socket} .verdict")
    expect(verdict).to_have_text(re.compile(r"^(PASS|FAIL|ERROR|ABORTED)$"), timeout=RUN_TIMEOUT_MS)
    return verdict.inner_text(), page.locator(f"#socket-{socket} .reasons").inner_text()


def _pdf_text(pdf: bytes) -> str:
    need("pdftotext")
    out = subprocess.run(["pdftotext", "-", "-"], input=pdf, capture_output=True, timeout=30)
    return out.stdout.decode("utf-8", errors="replace")


def _scan(page: Page, socket: int, serial: str) -> None:
    field = page.locator(f"#serial-{socket}")
    field.fill(serial)
    field.press("Enter")


def test_pass_and_fail_parts_with_progress_and_certificates(
    sim_station: SimStation, page: Page
) -> None:
    page.goto(sim_station.url)
    expect(page.locator(".inst[data-name='rate table'] [data-light=connected]")).to_have_class(
        re.compile(r"\bon\b")
    )
    _scan(page, 1, PASS_SERIAL)
    expect(page.locator("#serial-2")).to_be_focused()  # Enter moved on to the next socket
    _scan(page, 2, FAIL_SERIAL)
    expect(page.locator("#start-btn")).to_be_focused()
    page.click("#start-btn")
    expect(page.locator("#progress")).to_be_visible()
    # Progress advances: steps completed, bar moving, time remaining shown.
    expect(page.locator("#step-list li.done")).not_to_have_count(0, timeout=RUN_TIMEOUT_MS)
    expect(page.locator("#remaining")).to_contain_text(re.compile(r"\d+ (s|min) left"))
    expect(page.locator("#socket-2 .socket-state")).to_have_text("RUNNING")
    fraction = page.evaluate("parseFloat(document.getElementById('bar-fill').style.width)")
    assert fraction > 0
    verdict, reasons = _verdict(page, 1)
    assert verdict == "PASS", reasons
    first_ms = page.evaluate("window.__ui.firstProgressMs")
    assert first_ms is not None and first_ms > 0
    assert page.evaluate("S.chart[1].t_s.length") > 10  # the live chart got samples
    # The failing part: FAIL in large type with the failing measurement and its limits.
    fail_box = page.locator("#socket-2 .verdict-box")
    verdict, reasons = _verdict(page, 2)
    assert verdict == "FAIL", reasons
    expect(fail_box).to_have_class(re.compile(r"\bFAIL\b"))
    # in plain words on the socket, with the disposition from the product file
    expect(fail_box.locator(".reasons")).to_contain_text(
        re.compile(r"Bias too high: 14\.\d deg/s, limit \+/-10 deg/s")
    )
    expect(fail_box.locator(".disposition")).to_have_text("Red bin: do not ship")
    # the engineering names in the socket's detail view
    page.click("#socket-2 .socket-head")
    expect(page.locator("#detail-failed")).to_contain_text(
        re.compile(r"raw_bias_dps @ \S+: 14\.\d+ deg/s \(limits -10 .. 10\)")
    )
    page.click("#detail-close")
    # Certificates one touch away, and they are real PDFs of those parts.
    for socket, serial in ((1, PASS_SERIAL), (2, FAIL_SERIAL)):
        link = page.locator(f"#socket-{socket} a.certificate")
        expect(link).to_be_visible()
        with page.context.expect_page() as new_tab:
            link.click()
        assert new_tab.value.url.endswith(".pdf")
        pdf = httpx.get(sim_station.url + (link.get_attribute("href") or ""))
        assert pdf.status_code == 200 and pdf.content.startswith(b"%PDF")
        assert serial in (pdf.headers.get("content-disposition") or "")
        text = _pdf_text(pdf.content)
        if text is not None:  # poppler-utils present (CI installs them): it is that part's
            assert serial in text and ("PASS" if socket == 1 else "FAIL") in text
    # Ready for the next part, the last result still visible.
    expect(page.locator("#serial-1")).to_have_value("")
    expect(page.locator("#start-btn")).to_be_enabled()
    expect(page.locator("#socket-1 .verdict")).to_have_text("PASS")
    # The review screen lists both with the yield.
    page.goto(sim_station.url + "/review")
    expect(page.locator("#runs tr")).to_have_count(2)
    expect(page.locator("#sum-yield b")).to_have_text("50.0 %")


def test_abort_mid_run_reload_and_second_start(sim_station: SimStation, page: Page) -> None:
    page.goto(sim_station.url)
    _scan(page, 1, "SIM-0002")
    page.click("#start-btn")
    expect(page.locator("#step-name")).to_contain_text(
        re.compile(r"(Heating to|Cooling to|Settling at) -?\d+ C"), timeout=RUN_TIMEOUT_MS
    )
    # A second Start while running is refused with a message.
    with sim_station.client() as client:
        r = client.post("/api/start", json={"serials": {"2": "SIM-0003"}})
    assert r.status_code == 409 and "already in progress" in r.json()["error"]
    # The page survives a reload mid-run and shows the run in progress.
    page.reload()
    expect(page.locator("#progress")).to_be_visible()
    expect(page.locator("#serial-1")).to_have_value("SIM-0002")
    expect(page.locator("#start-btn")).to_be_disabled()
    page.click("#abort-btn")
    expect(page.locator("#abort-dialog")).to_be_visible()
    page.click("#abort-confirm")
    verdict, reasons = _verdict(page, 1)
    assert verdict == "ABORTED", reasons
    expect(page.locator("#safe-state")).to_have_text(re.compile("^Bench safe"))
    truth = sim_station.truth()
    assert truth["safe"]["all"] is True
    assert truth["table"]["enabled"] is False and truth["supply"]["output"] is False


def test_bad_serial_refused_on_the_page(sim_station: SimStation, page: Page) -> None:
    page.goto(sim_station.url)
    _scan(page, 1, "12345")
    expect(page.locator("#socket-1 .serial-msg")).to_contain_text("is not a GYR-130")
    product = yaml.safe_load((sim_station.config / "products" / "gyr130.yaml").read_text())
    expect(page.locator("#socket-1 .serial-msg")).to_contain_text(product["serial_pattern"])
    page.click("#start-btn")
    expect(page.locator("#message")).to_contain_text("'12345' is not a GYR-130")
    expect(page.locator("#progress")).to_be_hidden()


def test_operator_cannot_reach_procedure_selection(sim_station: SimStation, page: Page) -> None:
    page.goto(sim_station.url)
    expect(page.locator("#procedure-name")).to_have_text("ui-test-short")
    expect(page.locator("#engineer-panel")).to_be_hidden()
    expect(page.locator("#procedure-select option")).to_have_count(0)
    r = page.request.post(
        sim_station.url + "/api/select",
        data={"procedure": str(sim_station.config / "procedures/eol-rate-table.yaml")},
        headers={"X-CSRF-Token": page.evaluate("S.csrf")},  # the page's session, not engineer
    )
    assert r.status == 403 and "engineer role" in r.json()["error"]
    expect(page.locator("#procedure-name")).to_have_text("ui-test-short")


def test_engineer_selects_procedure_after_password(sim_station: SimStation, page: Page) -> None:
    page.goto(sim_station.url)
    page.click("#engineer-btn")
    page.fill("#password", "not-the-password")
    page.press("#password", "Enter")
    expect(page.locator("#login-msg")).to_contain_text("wrong engineer password")
    expect(page.locator("#engineer-panel")).to_be_hidden()
    page.fill("#password", ENGINEER_PASSWORD)
    page.press("#password", "Enter")
    expect(page.locator("#engineer-panel")).to_be_visible()
    expect(page.locator("#procedure-select option", has_text="eol-rate-table")).to_have_count(1)
    options = page.locator("#procedure-select option").all_inner_texts()
    assert {"eol-rate-table", "ui-test-short"} <= set(options)
    page.select_option("#procedure-select", label="eol-rate-table")
    page.click("#apply-selection")
    expect(page.locator("#procedure-name")).to_have_text("eol-rate-table")
    page.select_option("#procedure-select", label="ui-test-short")  # leave it as found
    page.click("#apply-selection")
    expect(page.locator("#procedure-name")).to_have_text("ui-test-short")


def test_state_never_publishes_the_bench_control_endpoint(sim_station: SimStation) -> None:
    """The bench's control channel answers anyone who reaches it: the station keeps it to
    itself (the pages get the bench's state through the station's own API)."""
    port = sim_station.bench_control.rpartition(":")[2]
    for path in ("/api/state", "/api/session", "/"):
        text = httpx.get(sim_station.url + path, timeout=10).text
        assert sim_station.bench_control not in text and f":{port}" not in text, path
    assert sim_station.truth()["safe"] is not None  # the endpoint is real, only unpublished
