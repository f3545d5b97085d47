"""The line operator's screen journey (issue 26, Deliver 2): `station ui --sim` through the
installed `station` command as README.md and docs/operator-screen.md show it, the first
START in chromium at the default speed (the bench in lockstep), with config/station.yaml's
eight sockets and with config/station-32.yaml's thirty-two: every socket ends PASS with its
certificate. The first START is the one that failed at a scaled clock (every socket ERROR
within 5 s: the bench's first lagged frames imported scipy inside its loop). Only `--port`
and `--out` are added to the documented command. Long: `station_grid`."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Browser, Page, expect  # noqa: E402

from station.ui.server import free_port  # noqa: E402

pytestmark = [pytest.mark.station_grid, pytest.mark.timeout(3600)]
ROOT = Path(__file__).resolve().parents[2]
STATION = Path(sys.executable).parent / "station"
RUN_TIMEOUT_MS = 40 * 60_000  # a whole 2 x 2 procedure, every socket, on a loaded 2-core box


class Screen:
    def __init__(self, url: str, log: Path, proc: subprocess.Popen[bytes]) -> None:
        self.url, self.log, self.proc = url, log, proc


def start_ui(tmp_path: Path, *args: str) -> Screen:
    if not STATION.exists():
        pytest.skip(f"no installed station command at {STATION}: run `python3 dev.py test`")
    port = free_port()
    log = tmp_path / "ui.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [str(STATION), "ui", "--sim", *args, "--port", str(port), "--out",
             str(tmp_path / "runs")],
            cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while True:
        assert proc.poll() is None, log.read_text()[-3000:]
        try:
            httpx.get(url + "/api/state", timeout=2).raise_for_status()
            return Screen(url, log, proc)
        except httpx.HTTPError:
            assert time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.2)


def stop_ui(screen: Screen) -> None:
    if screen.proc.poll() is None:
        screen.proc.send_signal(signal.SIGINT)
        try:
            screen.proc.wait(60)
        except subprocess.TimeoutExpired:
            screen.proc.kill()
            screen.proc.wait(10)


@pytest.fixture
def page(browser: Browser) -> Iterator[Page]:
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    pg = context.new_page()
    pg.set_default_timeout(30_000)
    try:
        yield pg
    finally:
        context.close()


def first_start(page: Page, screen: Screen, serials: dict[int, str]) -> float:
    """Scan every serial, press START once, wait for every verdict: PASS, each with its
    certificate. Returns the wall seconds from START to the last verdict."""
    page.goto(screen.url)
    expect(page.locator(".socket")).to_have_count(len(serials))
    for sock, serial in serials.items():
        field = page.locator(f"#serial-{sock}")
        field.fill(serial)
        field.press("Enter")
        expect(field).to_have_class(re.compile(r"\bok\b"))
    expect(page.locator("#start-btn")).to_be_enabled()
    t0 = time.monotonic()
    page.click("#start-btn")
    expect(page.locator("#progress")).to_be_visible()
    for sock in serials:
        verdict = page.locator(f"#socket-{sock} .verdict")
        expect(verdict).to_have_text(re.compile(r"^(PASS|FAIL|ERROR|ABORTED)$"),
                                     timeout=RUN_TIMEOUT_MS)
    wall = time.monotonic() - t0
    verdicts = {s: page.locator(f"#socket-{s} .verdict").inner_text() for s in serials}
    reasons = {s: page.locator(f"#socket-{s} .reasons").inner_text() for s in serials
               if verdicts[s] != "PASS"}
    assert verdicts == {s: "PASS" for s in serials}, (verdicts, reasons,
                                                      screen.log.read_text()[-2000:])
    state = httpx.get(screen.url + "/api/state", timeout=10).json()
    assert all(r["certificate_url"] for r in state["last"]["results"]), state["last"]
    return wall


def test_first_start_of_eight_sockets(tmp_path: Path, page: Page) -> None:
    """README: `station ui --sim` (config/station.yaml: eight sockets)."""
    screen = start_ui(tmp_path)
    try:
        assert "simulated bench running in lockstep" in screen.log.read_text()
        wall = first_start(page, screen, {k: f"SIM-010{k}" for k in range(1, 9)})
    finally:
        stop_ui(screen)
    print(f"8 sockets, first START to the last verdict: {wall:.0f} s wall")


def test_first_start_of_thirty_two_sockets(tmp_path: Path, page: Page) -> None:
    """docs/operator-screen.md: `station ui --sim --station config/station-32.yaml`."""
    screen = start_ui(tmp_path, "--station", "config/station-32.yaml")
    try:
        wall = first_start(page, screen, {k: f"SIM-32{k:02d}" for k in range(1, 33)})
    finally:
        stop_ui(screen)
    print(f"32 sockets, first START to the last verdict: {wall:.0f} s wall")
