"""32 sockets on four fixture boards, in a real browser on the real station (`station ui
--sim`) and its simulated bench: every socket scanned, START, every socket running on one
1280 x 800 screen, legibly (none cut off, its fixture light inside it, serials in large
type), and every part streaming. docs/screenshots/operator-32-sim-running.png is its second
screenshot (in the test's tmp folder, copied there by hand). Marked station_grid: CI runs it
after the default run."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
import yaml

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Page, expect  # noqa: E402

from tests.ui.stationkit import (  # noqa: E402
    REPO,
    make_station_config,
    start_ui_process,
    stop_ui_process,
)

pytestmark = [pytest.mark.slow, pytest.mark.station_grid]
SOCKETS = 32
SPEED = 10.0  # 32 sockets at 100 Hz: a pace a loaded machine's station keeps up with


def _config_32(folder: Path) -> Path:
    """The UI tests' config folder with config/station-32.yaml's four boards and 32 parts."""
    make_station_config(folder)
    station = yaml.safe_load((folder / "station.yaml").read_text(encoding="utf-8"))
    boards = yaml.safe_load((REPO / "config" / "station-32.yaml").read_text(encoding="utf-8"))
    station["instruments"]["fixture"] = boards["instruments"]["fixture"]
    (folder / "station.yaml").write_text(yaml.safe_dump(station), encoding="utf-8")
    sim = {
        "speed": SPEED,
        "fixture": {"sockets": SOCKETS, "sockets_per_board": 8},
        "parts": [{"socket": s, "serial": f"SIM-{3200 + s:04d}"} for s in range(1, SOCKETS + 1)],
    }
    (folder / "sim.yaml").write_text(yaml.safe_dump(sim), encoding="utf-8")
    return folder


@pytest.mark.timeout(420)
def test_32_sockets_scanned_started_and_shown_running_on_one_screen(
    tmp_path: Path, page: Page
) -> None:
    folder = _config_32(tmp_path / "config")
    station = start_ui_process(folder, tmp_path / "ui.log", speed=SPEED)
    try:
        page.set_viewport_size({"width": 1280, "height": 800})
        page.goto(station.url)
        expect(page.locator("#socket-32")).to_be_visible()
        for s in range(1, SOCKETS + 1):
            field = page.locator(f"#serial-{s}")
            field.fill(f"SIM-{3200 + s:04d}")
            field.press("Enter")
        start = page.locator("#start-btn")
        expect(start).to_be_enabled(timeout=30_000)
        start.click()
        for s in (1, 8, 9, 16, 17, 24, 25, 32):  # a socket at each edge of every board
            expect(page.locator(f"#socket-{s} .socket-step")).not_to_be_empty(timeout=60_000)
        boxes = [page.locator(f"#socket-{s}").bounding_box() for s in range(1, SOCKETS + 1)]
        for s, box in enumerate(boxes, start=1):
            assert box is not None, f"socket {s} is not laid out"
            assert box["x"] >= 0 and box["y"] >= 0, f"socket {s} starts off the screen"
            assert box["x"] + box["width"] <= 1280 and box["y"] + box["height"] <= 800, (
                f"socket {s} is cut off at 1280 x 800"
            )
            assert box["width"] >= 100 and box["height"] >= 60, f"socket {s} is too small"
        width = page.evaluate("document.documentElement.scrollWidth")
        height = page.evaluate("document.documentElement.scrollHeight")
        assert width <= 1280 and height <= 800, f"the page is {width} x {height} px"
        expect(page.locator("#socket-32 .socket-label")).to_have_text(re.compile(r"32"))
        serial_px = float(
            page.locator("#serial-32").evaluate("e => parseFloat(getComputedStyle(e).fontSize)")
        )
        assert serial_px >= 16, "serials must stay readable from a metre away"
        for s in range(1, SOCKETS + 1):  # the fixture light inside its socket, not cut off
            light = page.locator(f"#socket-{s} .fixture-light").bounding_box()
            box = boxes[s - 1]
            assert light is not None and box is not None
            assert light["x"] + light["width"] <= box["x"] + box["width"], f"socket {s}'s light"
        page.screenshot(path=str(tmp_path / "operator-32-sim-running.png"))
        deadline = time.monotonic() + 120
        while True:  # every socket's part streams once it is powered and identified
            truth = station.truth()
            streaming = [s for s, v in truth["sockets"].items() if v.get("stream_enabled")]
            if len(streaming) == SOCKETS or time.monotonic() > deadline:
                break
            time.sleep(1.0)
        assert len(truth["sockets"]) == SOCKETS
        assert len(streaming) == SOCKETS, f"only sockets {sorted(streaming)} stream"
        page.screenshot(path=str(tmp_path / "operator-32-sim-streaming.png"))
    finally:
        stop_ui_process(station.process)
