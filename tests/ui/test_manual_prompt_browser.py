"""The manual stop prompt in a real browser on the real hand-turned station (issue 12).

`station ui --sim` runs in its own process on the station file of the hand-turned bench
(config/station-manual.yaml: no rate table, an inclinometer per fixture) with the simulated
hand of config/sim/manual.yaml, on the reduced procedure tests/procedures/data/manual_short.yaml
(one condition, two moves). At bench speed the prompt lasts a fraction of a second, so the page
records every showing of the banner with a MutationObserver installed before START; the test
then asserts what the operator saw: the yellow banner with the instruction, socket 1 outlined,
the banner cleared once the hand moved (kind="prompt_done"), and the run ending PASS.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

pytest.importorskip(
    "playwright.sync_api", reason="the playwright package is missing: pip install playwright"
)
from playwright.sync_api import Page, expect  # noqa: E402

from tests.ui.stationkit import (  # noqa: E402
    REPO,
    SIM_SPEED,
    SimStation,
    start_ui_process,
    stop_ui_process,
)

pytestmark = pytest.mark.slow
RUN_TIMEOUT_MS = 90_000
SERIAL = "SIM-0001"
PROMPT = "Turn socket 1's fixture by hand to the other stop"

# Records each change of the prompt banner: shown/hidden, its text, the outlined sockets.
_WATCH_PROMPT = """() => {
  window.__prompts = [];
  const banner = document.getElementById("prompt");
  const note = () => window.__prompts.push({
    shown: !banner.hidden,
    message: document.getElementById("prompt-message").textContent,
    sockets: document.getElementById("prompt-sockets").textContent,
    outlined: [...document.querySelectorAll(".socket.prompted")].map(e => e.id),
    colour: getComputedStyle(banner).backgroundColor,
  });
  new MutationObserver(note).observe(banner, {attributes: true, childList: true, subtree: true});
}"""


def _manual_station_config(folder: Path) -> Path:
    """A config folder holding config/station-manual.yaml pointed at the short procedure."""
    (folder / "procedures").mkdir(parents=True)
    (folder / "products").mkdir()
    for p in (REPO / "config" / "products").glob("*.yaml"):
        shutil.copy(p, folder / "products" / p.name)
    short = (REPO / "tests" / "procedures" / "data" / "manual_short.yaml").read_text("utf-8")
    short = short.replace("product: ../../../config/products/", "product: ../products/")
    (folder / "procedures" / "manual_short.yaml").write_text(short, encoding="utf-8")
    station = yaml.safe_load((REPO / "config" / "station-manual.yaml").read_text("utf-8"))
    station.update(
        output_folder="runs",
        results_db="runs/results.sqlite",
        procedure="procedures/manual_short.yaml",
        sim_config="sim.yaml",
    )
    (folder / "station.yaml").write_text(yaml.safe_dump(station), encoding="utf-8")
    sim = yaml.safe_load((REPO / "config" / "sim" / "manual.yaml").read_text("utf-8"))
    sim["speed"] = SIM_SPEED
    (folder / "sim.yaml").write_text(yaml.safe_dump(sim), encoding="utf-8")
    return folder / "station.yaml"


@pytest.fixture(scope="module")
def manual_station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimStation]:
    folder = tmp_path_factory.mktemp("manual") / "config"
    _manual_station_config(folder)
    station = start_ui_process(folder, folder.parent / "ui.log")
    try:
        yield station
    finally:
        stop_ui_process(station.process)


def test_manual_stop_prompt_shown_cleared_and_run_passes(
    manual_station: SimStation, page: Page
) -> None:
    page.goto(manual_station.url)
    expect(page.locator("#procedure-name")).to_have_text("eol-manual-stop-short")
    page.evaluate(_WATCH_PROMPT)
    field = page.locator("#serial-1")
    field.fill(SERIAL)
    field.press("Enter")
    page.click("#start-btn")
    expect(page.locator("#progress")).to_be_visible()
    verdict = page.locator("#socket-1 .verdict")
    expect(verdict).to_have_text(re.compile(r"^(PASS|FAIL|ERROR|ABORTED)$"), timeout=RUN_TIMEOUT_MS)
    reasons = page.locator("#socket-1 .reasons").inner_text()
    assert verdict.inner_text() == "PASS", reasons
    seen: list[dict] = page.evaluate("window.__prompts")
    shown = [s for s in seen if s["shown"]]
    assert shown, f"the prompt banner never appeared: {seen}"
    assert all(s["message"] == PROMPT for s in shown), shown
    assert all(s["outlined"] == ["socket-1"] for s in shown), shown
    assert any(s["sockets"] == "Socket 1" for s in shown), shown
    # Each prompt was cleared after the hand's move: the banner ends hidden, nothing outlined.
    assert not seen[-1]["shown"], seen
    expect(page.locator("#prompt")).to_be_hidden()
    expect(page.locator("#socket-1.prompted")).to_have_count(0)
    assert all(s["colour"] == "rgb(253, 230, 138)" for s in shown), shown  # yellow #fde68a
