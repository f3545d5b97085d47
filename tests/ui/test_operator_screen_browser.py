"""Issue 17's must-show: the operator screen on a 1280 x 800 touch screen, against the fake
runner (the same page against the real engine is in test_station_sim.py).

Eight running sockets with START, ABORT and progress in view without scrolling (and 16 and
32 as a dense grid); plain words for steps, conditions and failures; START disabled with the
reason while an instrument is down, a serial is scanned twice or no operator is signed in;
the operator prompt of a manual step; the screen in German.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Browser, Page, Route, expect  # noqa: E402

from station.ui.app import create_app  # noqa: E402
from station.ui.controller import Controller  # noqa: E402
from station.ui.history import History  # noqa: E402
from station.ui.hub import Hub  # noqa: E402
from station.ui.instruments import InstrumentLight  # noqa: E402
from station.ui.server import BackgroundServer, serve_in_thread  # noqa: E402
from tests.ui.conftest import _HASH  # noqa: E402
from tests.ui.fake_runner import FakeRunner  # noqa: E402

WIDTH, HEIGHT = 1280, 800


class Line:
    """The UI around a fake runner with `n` sockets, served on a free port."""

    def __init__(self, tmp_path: Path, n: int, password_hash: str | None = _HASH) -> None:
        self.runner = FakeRunner(tmp_path / "runs", sockets=list(range(1, n + 1)), step_s=0.3)
        self.controller = Controller(self.runner, Hub())
        app = create_app(
            self.controller, History(tmp_path / "runs"), engineer_password_hash=password_hash
        )
        self.server: BackgroundServer = serve_in_thread(app, before_stop=self.controller.hub.close)

    @property
    def url(self) -> str:
        return self.server.url

    def close(self) -> None:
        self.runner.close()
        self.server.stop()


@pytest.fixture
def line(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Line]:
    n = getattr(request, "param", 8)
    ln = Line(tmp_path, n)
    try:
        yield ln
    finally:
        ln.close()


def _screen(browser: Browser, locale: str = "en-US") -> Page:
    context = browser.new_context(viewport={"width": WIDTH, "height": HEIGHT}, locale=locale)
    page = context.new_page()
    page.set_default_timeout(10_000)
    return page


@pytest.fixture
def screen(browser: Browser) -> Iterator[Page]:
    page = _screen(browser)
    try:
        yield page
    finally:
        page.context.close()


def _scan(page: Page, socket: int, serial: str) -> None:
    field = page.locator(f"#serial-{socket}")
    field.fill(serial)
    field.press("Enter")


def _in_view(page: Page, selector: str) -> bool:
    box = page.locator(selector).bounding_box()
    assert box is not None, f"{selector} is not rendered"
    return (
        box["x"] >= 0
        and box["y"] >= 0
        and box["x"] + box["width"] <= WIDTH + 0.5
        and box["y"] + box["height"] <= HEIGHT + 0.5
    )


def _assert_one_screen(page: Page, n: int, *, running: bool = True) -> None:
    height = page.evaluate("document.documentElement.scrollHeight")
    width = page.evaluate("document.documentElement.scrollWidth")
    assert height <= HEIGHT and width <= WIDTH, f"the page is {width} x {height} px"
    progress = ["#progress", "#step-name", "#bar-fill"] if running else []
    for selector in ["#start-btn", "#abort-btn", *progress] + [
        f"#socket-{k}" for k in range(1, n + 1)
    ]:
        assert _in_view(page, selector), f"{selector} is outside the 1280 x 800 screen"


def test_eight_running_sockets_start_abort_and_progress_on_one_screen(
    line: Line, screen: Page
) -> None:
    line.runner.prompt = ("Turn socket 8's fixture by hand to the other stop", [8])  # holds
    screen.goto(line.url)
    for k in range(1, 9):
        _scan(screen, k, f"SIM-{k:04d}")
    screen.click("#start-btn")
    expect(screen.locator("#progress")).to_be_visible()
    expect(screen.locator("#socket-8 .socket-state")).to_have_text("RUNNING")
    expect(screen.locator("#step-list li.done").first).to_be_visible()
    expect(screen.locator("#prompt")).to_be_visible(timeout=15_000)  # the tallest state
    _assert_one_screen(screen, 8)
    # readable from a metre away: serial, step and verdict in large type
    serial_px = screen.evaluate(
        "parseFloat(getComputedStyle(document.getElementById('serial-1')).fontSize)"
    )
    step_px = screen.evaluate(
        "parseFloat(getComputedStyle(document.querySelector('#socket-1 .socket-step')).fontSize)"
    )
    assert serial_px >= 24 and step_px >= 18
    light_px = screen.evaluate(
        "Math.min(...[...document.querySelectorAll('.inst b, .inst .light')]"
        ".map(e => Math.min(parseFloat(getComputedStyle(e).fontSize) || 99, e.offsetHeight)))"
    )
    assert light_px >= 16, "instrument lights must be readable"
    # a tap on a socket opens its detail with the chart, counted from the run's start
    screen.click("#socket-3 .socket-head")
    expect(screen.locator("#detail-dialog")).to_be_visible()
    expect(screen.locator("#detail-serial")).to_have_text("SIM-0003")
    assert screen.evaluate("S.chart[3].t_s[0]") == 0.0
    screen.click("#detail-close")
    screen.click("#abort-btn")  # while the run waits for the operator
    screen.click("#abort-confirm")
    expect(screen.locator("#prompt")).to_be_hidden()
    expect(screen.locator("#socket-8 .verdict")).to_have_text("ABORTED")
    _assert_one_screen(screen, 8, running=False)


@pytest.mark.parametrize("line", [16, 32], indirect=True)
def test_dense_grid_for_16_and_32_sockets(line: Line, screen: Page) -> None:
    n = len(line.runner.info.sockets)
    line.runner.prompt = ("Turn socket 1's fixture by hand to the other stop", [1])  # holds
    screen.goto(line.url)
    expect(screen.locator(f"#socket-{n}")).to_be_visible()
    for k in range(1, n + 1, 2):  # every other socket loaded
        _scan(screen, k, f"SIM-{k:04d}")
    screen.click("#start-btn")
    expect(screen.locator("#prompt")).to_be_visible(timeout=15_000)
    _assert_one_screen(screen, n)
    line.runner.answer()
    serial_px = screen.evaluate(
        f"parseFloat(getComputedStyle(document.getElementById('serial-{n}')).fontSize)"
    )
    assert serial_px >= 16
    expect(screen.locator(f"#socket-{n - 1} .verdict")).to_have_text("PASS", timeout=20_000)
    _assert_one_screen(screen, n, running=False)


def test_plain_words_for_steps_conditions_failures_and_dispositions(
    line: Line, screen: Page
) -> None:
    line.runner.prompt = ("Turn both fixtures by hand", [1, 2])  # holds the run there
    screen.goto(line.url)
    _scan(screen, 1, "SIM-0001")
    _scan(screen, 2, "BAD-0002")
    screen.click("#start-btn")
    expect(screen.locator("#prompt")).to_be_visible(timeout=15_000)
    held = "Turning the fixture by hand, at 45 C, supply 5.25 V"
    expect(screen.locator("#step-name")).to_have_text(held)
    expect(screen.locator("#remaining")).to_have_text(re.compile(r"^\d+ s left$"))
    expect(screen.locator("#socket-1 .socket-step")).to_have_text(held)
    steps = screen.locator("#step-list li").all_inner_texts()
    assert "Heating to 45 C, supply 5.25 V" in steps
    assert "Turning the rate table, at 45 C, supply 5.25 V" in steps
    assert not any("T45_V5.25" in s or "_" in s for s in steps), steps
    # the engineering name stays in the detail view
    screen.click("#socket-1 .socket-head")
    expect(screen.locator("#detail-step")).to_have_text(re.compile(r"T45_V5\.25"))
    screen.click("#detail-close")
    line.runner.answer()
    expect(screen.locator("#socket-2 .verdict")).to_have_text("FAIL", timeout=15_000)
    expect(screen.locator("#socket-2 .reasons")).to_have_text(
        "Bias too high: 14.2 deg/s, limit +/-10 deg/s"
    )
    expect(screen.locator("#socket-2 .disposition")).to_have_text("Red bin: do not ship")
    expect(screen.locator("#socket-1 .disposition")).to_have_text("Place in tray A")


def test_start_disabled_with_the_reason_while_an_instrument_is_down(
    line: Line, screen: Page
) -> None:
    line.runner.lights[0] = InstrumentLight("rate table", False, True, False, "", "no answer")
    line.controller.refresh_instruments()
    screen.goto(line.url)
    _scan(screen, 1, "SIM-0001")
    expect(screen.locator("#start-btn")).to_be_disabled()
    expect(screen.locator("#start-reason")).to_contain_text("rate table is not reachable")
    # the server refuses too: no record for a part never tested
    csrf = screen.evaluate("S.csrf")
    r = screen.request.post(
        line.url + "/api/start", data={"serials": {"1": "SIM-0001"}}, headers={"X-CSRF-Token": csrf}
    )
    assert r.status == 409 and "rate table is not reachable" in r.json()["error"]
    assert line.runner.started == []
    # the table answers again: START comes back, the reason goes
    line.runner.lights[0] = InstrumentLight("rate table", True, True, False, "2027-06-30")
    line.controller.refresh_instruments()
    expect(screen.locator("#start-btn")).to_be_enabled()
    expect(screen.locator("#start-reason")).to_be_hidden()


def test_a_fixture_down_blocks_only_its_own_socket(line: Line, screen: Page) -> None:
    line.runner.lights.append(InstrumentLight("fixture 2", False, None, False, socket=2))
    line.controller.refresh_instruments()
    screen.goto(line.url)
    _scan(screen, 1, "SIM-0001")
    expect(screen.locator("#start-btn")).to_be_enabled()
    _scan(screen, 2, "SIM-0002")
    expect(screen.locator("#start-btn")).to_be_disabled()
    expect(screen.locator("#start-reason")).to_contain_text("fixture 2 is not reachable")


def test_duplicate_serial_flagged_at_scan(line: Line, screen: Page) -> None:
    screen.goto(line.url)
    _scan(screen, 1, "SIM-0007")
    _scan(screen, 2, "SIM-0007")
    expect(screen.locator("#socket-2 .serial-msg")).to_contain_text("Already scanned in socket 1")
    expect(screen.locator("#serial-2")).to_have_class(re.compile(r"\bbad\b"))
    expect(screen.locator("#start-btn")).to_be_disabled()
    expect(screen.locator("#start-reason")).to_contain_text("SIM-0007 is scanned in sockets 1, 2")
    _scan(screen, 2, "SIM-0008")
    expect(screen.locator("#start-btn")).to_be_enabled()


def test_a_late_validation_reply_leaves_the_focus_where_the_operator_moved(
    line: Line, screen: Page
) -> None:
    """The reply to socket 1's scan arrives after the operator has moved to socket 3: the
    focus stays in socket 3, so the next scan cannot land in socket 2 (CI once saw a serial
    typed into socket 31 go to socket 30 this way)."""
    held: list[Route] = []

    def hold_first(route: Route) -> None:
        if held:
            route.continue_()
        else:
            held.append(route)

    screen.goto(line.url)
    screen.route("**/api/validate", hold_first)
    _scan(screen, 1, "SIM-0001")
    for _ in range(200):  # the request is parked by the handler, on the page's own time
        if held:
            break
        screen.wait_for_timeout(10)
    assert held, "socket 1's validation request never reached the route"
    screen.locator("#serial-3").fill("SIM-0003")  # the operator taps socket 3 and scans
    held[0].continue_()
    expect(screen.locator("#serial-1")).to_have_class(re.compile(r"\bok\b"))
    assert screen.evaluate("document.activeElement.id") == "serial-3"
    screen.keyboard.press("Enter")
    expect(screen.locator("#serial-3")).to_have_class(re.compile(r"\bok\b"))
    expect(screen.locator("#serial-2")).to_have_value("")
    expect(screen.locator("#serial-3")).to_have_value("SIM-0003")


def test_operator_prompt_shown_and_cleared(line: Line, screen: Page) -> None:
    message = "Turn socket 1's fixture by hand to the other stop"
    line.runner.prompt = (message, [1])
    screen.goto(line.url)
    _scan(screen, 1, "SIM-0001")
    _scan(screen, 2, "SIM-0002")
    screen.click("#start-btn")
    expect(screen.locator("#prompt")).to_be_visible(timeout=15_000)
    expect(screen.locator("#prompt-message")).to_have_text(message)
    expect(screen.locator("#prompt-sockets")).to_have_text("Socket 1")
    expect(screen.locator("#socket-1")).to_have_class(re.compile(r"\bprompted\b"))
    expect(screen.locator("#socket-2")).not_to_have_class(re.compile(r"\bprompted\b"))
    screen.reload()  # a reload keeps the prompt (it is part of the run's state)
    expect(screen.locator("#prompt-message")).to_have_text(message)
    line.runner.answer()
    expect(screen.locator("#prompt")).to_be_hidden()
    expect(screen.locator("#socket-1 .verdict")).to_have_text("PASS", timeout=15_000)


def test_work_order_and_lot_go_with_the_run(line: Line, screen: Page) -> None:
    screen.goto(line.url)
    screen.fill("#work-order", "WO-4711")
    screen.fill("#lot", "L-26-47")
    _scan(screen, 1, "SIM-0001")
    screen.click("#start-btn")
    expect(screen.locator("#socket-1 .verdict")).to_have_text("PASS", timeout=15_000)
    started = line.runner.started[-1]
    assert (started.work_order, started.lot) == ("WO-4711", "L-26-47")
    expect(screen.locator("#work-order")).to_have_value("WO-4711")  # kept for the next parts


def test_stale_refusal_cleared_when_the_run_ends(line: Line, screen: Page) -> None:
    line.runner.prompt = ("Turn the fixture by hand", [1])  # holds the run there
    screen.goto(line.url)
    _scan(screen, 1, "SIM-0001")
    screen.click("#start-btn")
    expect(screen.locator("#prompt")).to_be_visible(timeout=15_000)
    screen.evaluate("start()")  # a second Start (e.g. a double tap) is refused with a message
    expect(screen.locator("#message")).to_contain_text("already in progress")
    line.runner.answer()
    expect(screen.locator("#socket-1 .verdict")).to_have_text("PASS", timeout=15_000)
    expect(screen.locator("#message")).to_have_text("")


def test_engineer_button_only_where_a_password_exists(
    tmp_path: Path, line: Line, screen: Page
) -> None:
    screen.goto(line.url)
    expect(screen.locator("#engineer-btn")).to_be_visible()
    bare = Line(tmp_path / "bare", 2, password_hash=None)
    try:
        screen.goto(bare.url)
        expect(screen.locator("#station-name")).to_have_text("Fake station")
        expect(screen.locator("#signin-btn")).to_be_visible()
        expect(screen.locator("#engineer-btn")).to_be_hidden()
    finally:
        bare.close()


def test_the_screen_in_german(line: Line, browser: Browser) -> None:
    line.runner.prompt = ("Vorrichtung von Hand drehen", [1])  # holds the run there
    page = _screen(browser, locale="de-DE")
    try:
        page.goto(line.url)
        expect(page.locator("html")).to_have_attribute("lang", "de")
        expect(page.locator("#abort-btn")).to_have_text("ABBRUCH")
        expect(page.locator("#socket-1 .socket-label")).to_have_text("Sockel 1")
        expect(page.locator("#serial-1")).to_have_attribute("placeholder", "Seriennummer scannen")
        expect(page.locator(".inst[data-name='rate table'] b")).to_have_text("Drehtisch")
        _scan(page, 1, "BAD-0001")
        page.click("#start-btn")
        expect(page.locator("#prompt-sockets")).to_have_text("Sockel 1", timeout=15_000)
        expect(page.locator("#step-name")).to_have_text(
            "Vorrichtung von Hand drehen, bei 45 °C, Versorgung 5,25 V"
        )
        expect(page.locator("#step-list li").nth(2)).to_have_text(
            "Heizen auf 45 °C, Versorgung 5,25 V"
        )
        line.runner.answer()
        expect(page.locator("#socket-1 .verdict")).to_have_text("n.i.O.", timeout=15_000)
        expect(page.locator("#socket-1 .reasons")).to_have_text(
            "Nullpunkt zu hoch: 14,2 deg/s, Grenze +/-10 deg/s"
        )
        _assert_one_screen(page, 8, running=False)
    finally:
        page.context.close()
