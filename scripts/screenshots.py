"""Screenshots of each screen for the README: docs/screenshots/*.png.

Runs the real station (`station ui --sim`, short test procedure, one good part and one made
to fail) and Debian's chromium at the line's 1280 x 800 touch screen, walks through the
operator's and the engineer's screens and the review screen, and saves one PNG per screen.
Then the screens a two-socket bench cannot show (8 and 32 sockets, an operator prompt, START
blocked by an instrument, the German catalog) against the UI tests' fake runner.

    python3 scripts/screenshots.py [--out docs/screenshots]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from station.ui.headless import chromium, chromium_missing_reason, wait_js  # noqa: E402
from tests.ui.stationkit import (  # noqa: E402
    ENGINEER_PASSWORD,
    FAIL_SERIAL,
    PASS_SERIAL,
    make_station_config,
    start_ui_process,
    stop_ui_process,
)

RUN_TIMEOUT_MS = 120_000
SCREEN = {"width": 1280, "height": 800}


def shoot(page, out: Path, name: str) -> None:  # noqa: ANN001
    path = out / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)
    print(path)


def fake_line(tmp: Path, n: int, step_s: float):  # noqa: ANN201
    """The UI around the tests' fake runner with n sockets: (runner, controller, server)."""
    from station.ui.app import create_app
    from station.ui.controller import Controller
    from station.ui.history import History
    from station.ui.hub import Hub
    from station.ui.server import serve_in_thread
    from tests.ui.conftest import _HASH
    from tests.ui.fake_runner import FakeRunner

    runner = FakeRunner(tmp / f"runs-{n}", sockets=list(range(1, n + 1)), step_s=step_s)
    controller = Controller(runner, Hub())
    app = create_app(controller, History(tmp / f"runs-{n}"), engineer_password_hash=_HASH)
    return runner, controller, serve_in_thread(app, before_stop=controller.hub.close)


def scan_all(page, n: int) -> None:  # noqa: ANN001
    for k in range(1, n + 1):
        serial = f"{'BAD' if k % 5 == 3 else 'SIM'}-{k:04d}"
        page.fill(f"#serial-{k}", serial)
        page.press(f"#serial-{k}", "Enter")
        page.wait_for_selector(f"#serial-{k}.ok")


def fake_shots(browser, tmp: Path, out: Path) -> None:  # noqa: ANN001
    from station.ui.instruments import InstrumentLight

    shots = (
        (8, "en-US", "operator-eight-running", "operator-eight-verdicts"),
        (32, "en-US", "operator-32-running", "operator-32-verdicts"),
        (8, "de-DE", "operator-german-running", "operator-german-verdicts"),
    )
    for n, locale, running, verdicts in shots:
        runner, _, server = fake_line(tmp, n, step_s=1.5)
        try:
            page = browser.new_context(viewport=SCREEN, locale=locale).new_page()
            page.goto(server.url)
            scan_all(page, n)
            page.click("#start-btn")
            page.wait_for_selector("#step-list li.current")
            time.sleep(3.5)
            shoot(page, out, running)
            page.wait_for_selector(f"#socket-{n} .verdict-box:not([hidden])", timeout=60_000)
            shoot(page, out, verdicts)
            page.context.close()
        finally:
            runner.close()
            server.stop()
    runner, controller, server = fake_line(tmp, 8, step_s=0.5)
    try:
        runner.prompt = ("Turn socket 1's fixture by hand to the other stop", [1])
        page = browser.new_context(viewport=SCREEN).new_page()
        page.goto(server.url)
        scan_all(page, 2)
        page.click("#start-btn")
        page.wait_for_selector("#prompt:not([hidden])", timeout=30_000)
        shoot(page, out, "operator-prompt")
        runner.answer()
        page.wait_for_selector("#socket-1 .verdict-box:not([hidden])", timeout=30_000)
        runner.lights[0] = InstrumentLight("rate table", False, True, False, "", "no answer")
        controller.refresh_instruments()
        page.fill("#serial-1", "SIM-0101")
        page.press("#serial-1", "Enter")
        page.wait_for_selector("#start-btn:disabled")
        shoot(page, out, "operator-start-blocked")
        page.context.close()
    finally:
        runner.close()
        server.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "screenshots"))
    args = ap.parse_args()
    reason = chromium_missing_reason()
    if reason:
        print(f"cannot take screenshots: {reason}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ui-shots-") as tmp:
        config = Path(tmp) / "config"
        make_station_config(config)
        station = start_ui_process(config, Path(tmp) / "ui.log")
        try:
            with chromium() as browser:
                page = browser.new_page(viewport=SCREEN)
                page.set_default_timeout(RUN_TIMEOUT_MS)
                page.goto(station.url)
                page.click("#signin-btn")  # an open station: the operator's name
                page.fill("#operator-input", "ana")
                page.press("#operator-input", "Enter")
                page.wait_for_selector("#signin-dialog:not([open])", state="attached")
                # A bad serial refused with its reason.
                page.fill("#serial-1", "12345")
                page.press("#serial-1", "Enter")
                page.wait_for_selector("#serial-1.bad")
                shoot(page, out, "operator-bad-serial")
                # Both parts scanned, ready to start.
                page.fill("#serial-1", PASS_SERIAL)
                page.press("#serial-1", "Enter")
                page.fill("#serial-2", FAIL_SERIAL)
                page.press("#serial-2", "Enter")
                page.wait_for_selector("#serial-2.ok")
                shoot(page, out, "operator-ready")
                # Mid-run: progress per step and condition, live chart.
                page.click("#start-btn")
                done_steps = "document.querySelectorAll('#step-list li.done').length >= 6"
                wait_js(page, done_steps, timeout_s=120)
                shoot(page, out, "operator-running")
                page.click("#abort-btn")
                shoot(page, out, "operator-abort-confirm")
                page.click("#abort-cancel")
                # Verdicts: PASS and FAIL with the failing measurement, certificates.
                page.wait_for_selector("#socket-2 .verdict-box:not([hidden])")
                shoot(page, out, "operator-verdicts")
                # Engineer: procedure and product selection after the password.
                page.click("#engineer-btn")
                page.fill("#password", ENGINEER_PASSWORD)
                page.press("#password", "Enter")
                page.wait_for_selector("#engineer-panel:not([hidden])")
                page.wait_for_selector("#procedure-select option", state="attached")
                shoot(page, out, "engineer-selection")
                page.click("#engineer-btn")  # log out again
                page.wait_for_selector("#engineer-panel", state="hidden")
                # A tap on the failed socket: its chart and the engineering names.
                page.click("#socket-2 .socket-head")
                page.wait_for_selector("#detail-dialog[open]")
                shoot(page, out, "operator-detail")
                page.click("#detail-close")
                # Review: history, filters, yield, certificates.
                page.goto(station.url + "/review")
                page.wait_for_selector("#runs tr")
                shoot(page, out, "review")
                fake_shots(browser, Path(tmp), out)
        finally:
            stop_ui_process(station.process)
    return 0


if __name__ == "__main__":
    sys.exit(main())
