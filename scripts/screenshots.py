"""Screenshots of each screen for the README: docs/screenshots/*.png.

Runs the real station (`station ui --sim`, short test procedure, one good part and one made
to fail) and Debian's chromium, walks through the operator's and the engineer's screens and
the review screen, and saves one PNG per screen.

    python3 scripts/screenshots.py [--out docs/screenshots]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
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


def shoot(page, out: Path, name: str) -> None:  # noqa: ANN001
    path = out / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)
    print(path)


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
                page = browser.new_page(viewport={"width": 1280, "height": 860})
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
                # Review: history, filters, yield, certificates.
                page.goto(station.url + "/review")
                page.wait_for_selector("#runs tr")
                shoot(page, out, "review")
        finally:
            stop_ui_process(station.process)
    return 0


if __name__ == "__main__":
    sys.exit(main())
