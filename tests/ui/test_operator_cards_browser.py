"""The operator's cards at 8 sockets on the 1280 x 800 screen (issue 26 (14)): nothing cut
off (was "stop_table_consisten..." and the Certificate button cut off), plain words only on a
card (the engineering names are in the socket's detail view), the three instrument lights
labelled, and the Lot field on the selection line."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Browser, Page, expect  # noqa: E402

from procedures.runtime.record import Measurement, Outcome, Verdict  # noqa: E402
from station.ui.history import result_from_record  # noqa: E402
from tests.ui.test_operator_screen_browser import HEIGHT, WIDTH, Line  # noqa: E402

pytestmark = pytest.mark.slow

MARGINAL_REASON = "all measurements within limits (1 marginal: stop_table_consistency@T45_V5.25)"
ERROR_REASON = (
    "rate table: the rate table at 127.0.0.1:37143 did not answer a read of registers 20..30 "
    "within 1 s: check the controller is running (in step thermal)"
)


def _line(tmp_path: Path) -> Line:
    """Eight sockets: marginal PASSes, a FAIL at three conditions, an ERROR and an ABORTED."""
    line = Line(tmp_path, 8)
    runner = line.runner
    write = runner._write

    def varied(socket: int, serial: str, request: object, aborted: bool) -> dict:
        result = write(socket, serial, request, aborted)
        folder = Path(result["run_folder"])
        from procedures.runtime.record import read_record, write_record

        record = read_record(folder)
        if socket <= 4:
            record.reason = MARGINAL_REASON
            record.measurements.append(Measurement(
                name="stop_table_consistency", value=2.4, units="1", low=-3, high=3,
                outcome=Outcome.MARGINAL, condition="T45_V5.25"))
        elif socket <= 6:
            record.verdict = Verdict.FAIL
            record.reason = "out of limits: stop_table_consistency@T45_V5.25, ..."
            record.measurements = [Measurement(
                name="stop_table_consistency", value=-3.2417 - k, units="1", low=-3, high=3,
                outcome=Outcome.FAIL, condition=c)
                for k, c in enumerate(["T25_V4.75", "T45_V5.25", "T45_V4.75"])]
        elif socket == 7:
            record.verdict, record.reason, record.measurements = Verdict.ERROR, ERROR_REASON, []
        else:
            record.verdict, record.measurements = Verdict.ABORTED, []
            record.reason = "aborted: the operator pressed ABORT on the station screen, in step x"
        write_record(folder, record)
        (folder / "certificate.pdf").write_bytes(b"%PDF-1.4\n%%EOF\n")
        return result_from_record(record, folder)

    runner._write = varied  # type: ignore[method-assign]
    # the shipped files' names, as `station ui --sim` shows them
    from station.ui.runner_adapter import Choice, ProductChoice

    runner.procedures = lambda: [  # type: ignore[method-assign]
        Choice("eol-rate-table", "/cfg/full.yaml")]
    runner.products = lambda: [ProductChoice(  # type: ignore[method-assign]
        "GYR-130 yaw-rate gyroscope", "/cfg/gyr130.yaml", r"^[A-Z]{2,4}-[0-9]{4}$", "ABCD-1234",
        {"PASS": "Place in tray A", "FAIL": "Red bin: do not ship",
         "ERROR": "Retest once, then call the engineer", "ABORTED": "Retest the part"})]
    return line


@pytest.fixture
def line(tmp_path: Path) -> Iterator[Line]:
    ln = _line(tmp_path)
    try:
        yield ln
    finally:
        ln.close()


@pytest.fixture
def screen(browser: Browser) -> Iterator[Page]:
    context = browser.new_context(viewport={"width": WIDTH, "height": HEIGHT})
    page = context.new_page()
    page.set_default_timeout(10_000)
    try:
        yield page
    finally:
        context.close()


# every text element of a card, and whether it is cut off: wider than its box, or outside the
# card (whose overflow is hidden)
CLIPPED = """() => [...document.querySelectorAll('.socket')].flatMap(card => {
  const c = card.getBoundingClientRect();
  return [...card.querySelectorAll(
      '.verdict, .verdict-serial, .disposition, .reasons li, .certificate, .socket-head span')]
    .filter(e => e.offsetParent !== null)
    .filter(e => { const r = e.getBoundingClientRect();
      return e.scrollWidth > e.clientWidth + 1 || r.bottom > c.bottom + 0.5
        || r.right > c.right + 0.5; })
    .map(e => card.id + ' ' + e.className + ': ' + e.textContent);
})"""


def test_eight_finished_cards_show_everything_in_plain_words(line: Line, screen: Page) -> None:
    screen.goto(line.url)
    for k in range(1, 9):
        field = screen.locator(f"#serial-{k}")
        field.fill(f"SIM-{k:04d}")
        field.press("Enter")
    screen.click("#start-btn")
    expect(screen.locator("#socket-8 .verdict")).to_have_text("ABORTED", timeout=30_000)
    screen.screenshot(path=str(Path(line.runner.out_dir).parent / "cards.png"))
    assert screen.evaluate(CLIPPED) == []
    for k in range(1, 9):  # the certificate button whole, inside its card
        expect(screen.locator(f"#socket-{k} .certificate")).to_be_visible()
    cards = screen.evaluate("[...document.querySelectorAll('.socket')].map(c => c.innerText)")
    for text in cards:
        assert "_" not in text and "@" not in text and "127.0.0.1" not in text, text
    assert "1 marginal" in cards[0], cards[0]
    assert "Stopped by an error: tap for the details" in cards[6], cards[6]
    # the engine's own words are in the socket's detail view
    screen.click("#socket-7 .socket-head")
    expect(screen.locator("#detail-reason")).to_have_text(ERROR_REASON)


def test_the_instrument_lights_are_labelled_and_lot_stays_on_its_line(
    line: Line, screen: Page
) -> None:
    screen.goto(line.url)
    legend = screen.locator(".inst-legend span")
    expect(legend).to_have_text(["Lights", "connected", "in cal", "fault"])
    # each label sits over its column of lights
    for k, light in enumerate(("connected", "calibration", "fault"), start=1):
        label = legend.nth(k).bounding_box()
        dot = screen.locator(f".inst >> nth=0 >> [data-light={light}]").bounding_box()
        assert label and dot
        assert abs((label["x"] + label["width"] / 2) - (dot["x"] + dot["width"] / 2)) < 2
    cut = screen.evaluate("[...document.querySelectorAll('.inst-legend span, .inst b')]"
                          ".filter(e => e.scrollWidth > e.clientWidth).map(e => e.textContent)")
    assert cut == [], cut  # "conne...", "rate ta..."
    order, lot = screen.locator("#work-order").bounding_box(), screen.locator("#lot").bounding_box()
    assert order and lot and abs(order["y"] - lot["y"]) < 1, (order, lot)  # was wrapped
    assert lot["x"] + lot["width"] <= WIDTH
