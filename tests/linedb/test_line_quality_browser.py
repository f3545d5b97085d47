"""The dashboard's quality numbers in a real chromium (issue 30, deliverable 4): the
"include simulated runs" switch (off by default) brings simulated runs back; Cpk below the
minimum reads "too few (n = 7, need 25)"; the control chart's axes carry values (numbers
up the side, start times along the bottom), the units, the centre line, the control limits
and the product's limits, each drawn at the height its value has on the axis."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from reports.lot_stats import MIN_CPK_N
from station.db.connect import dispose_all
from station.results_db import ResultsDB
from station.ui.headless import wait_js
from station.ui.server import serve_in_thread
from tests.linedb.linekit import line_app, line_runs, sign_in_page
from tests.linedb.test_line_quality import BENCH, N_BENCH, count_yields, simulated_runs


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, list[Any]]]:
    folder: Path = tmp_path_factory.mktemp("quality-page")
    real = [r.record for r in line_runs(60, ["EOL-A", "EOL-B"], seed=8, root=folder / "runs")]
    records = real + simulated_runs()
    db = ResultsDB(folder / "line.sqlite")
    db.add_records([(folder / "runs" / r.run_id, r) for r in records])
    server = serve_in_thread(line_app(db.engine))
    try:
        yield server.url, records
    finally:
        server.stop()
        dispose_all()


@pytest.fixture
def dashboard(line: tuple[str, list[Any]], page: Any) -> Any:
    sign_in_page(page, line[0])
    return page


def _show(page: Any, query: str) -> None:
    """Press Show and wait for the panels of this query (a newer refresh wins)."""
    page.click("#filters button[type=submit]")
    wait_js(page, f"document.body.dataset.query === {query!r}")


def _units_tests(records: list[Any]) -> str:
    units, tests, _, _ = count_yields(records)
    return f"{units} units, {tests} tests"


def test_simulated_runs_switch(line: tuple[str, list[Any]], dashboard: Any) -> None:
    _, records = line
    switch = dashboard.locator('#filters input[name="simulated"]')
    assert "include simulated runs" in dashboard.locator("#filters label.switch").inner_text()
    assert not switch.is_checked()
    real = [r for r in records if not r.simulated]
    box = dashboard.locator("#yield-all")
    assert box.inner_text().startswith(_units_tests(real))
    left_out = len(records) - len(real)
    note = dashboard.locator("#simulated-note").inner_text()
    assert note == f"{left_out} simulated runs left out"
    assert dashboard.locator(f'#stations .card[data-station="{BENCH}"]').count() == 0
    switch.check()
    _show(dashboard, "simulated=include")
    assert box.inner_text().startswith(_units_tests(records))
    assert "included" in dashboard.locator("#simulated-note").inner_text()
    assert dashboard.locator(f'#stations .card[data-station="{BENCH}"]').count() == 1


def test_cpk_too_few_reads_n_and_the_minimum(dashboard: Any) -> None:
    dashboard.locator('#filters input[name="simulated"]').check()
    dashboard.select_option('#filters select[name="station"]', BENCH)
    _show(dashboard, f"station={BENCH}&simulated=include")
    cell = dashboard.locator('#capability tr[data-name="bias_dps"] td.cpk')
    assert cell.inner_text() == f"too few (n = {N_BENCH}, need {MIN_CPK_N})"
    dashboard.locator('#filters input[name="simulated"]').uncheck()
    dashboard.select_option('#filters select[name="station"]', "")
    _show(dashboard, "")
    shown = dashboard.locator('#capability tr[data-name="bias_dps"] td.cpk').inner_text()
    assert re.fullmatch(r"-?\d+\.\d\d", shown), shown


_CHART = """() => {
  const svg = document.getElementById('chart');
  const y = (e) => Number(e.getAttribute('y1'));
  const one = (cls) => { const l = svg.querySelector('line.' + cls);
    return l && { value: Number(l.dataset.value), y: y(l) }; };
  return {
    ticks: [...svg.querySelectorAll('text.chart-tick')].map((t) => ({
      label: t.textContent, y: Number(t.getAttribute('y')) - 4 })),
    xticks: [...svg.querySelectorAll('text.chart-xtick')].map((t) => ({
      label: t.textContent, x: Number(t.getAttribute('x')), i: Number(t.dataset.index) })),
    units: svg.querySelector('text.chart-units')?.textContent,
    lines: Object.fromEntries(['chart-centre', 'chart-ucl', 'chart-lcl', 'chart-usl', 'chart-lsl']
      .map((c) => [c, one(c)])),
    labels: [...svg.querySelectorAll('text.chart-line-label')].map((t) => t.textContent),
  };
}"""


def test_chart_axes_units_and_limit_lines(line: tuple[str, list[Any]], dashboard: Any) -> None:
    url, _ = line
    api = dashboard.request.get(url + "/api/chart?coefficient=bias_dps").json()
    got = dashboard.evaluate(_CHART)
    ticks = got["ticks"]
    assert len(ticks) >= 3
    values = [float(t["label"]) for t in ticks]  # numeric tick labels
    assert values == sorted(values)
    assert all(a["y"] > b["y"] for a, b in zip(ticks, ticks[1:], strict=False))  # up the side
    assert got["units"] == "bias_dps (deg/s)"
    (v0, y0), (v1, y1) = (values[0], ticks[0]["y"]), (values[-1], ticks[-1]["y"])
    on_axis = {"chart-centre": api["centre"], "chart-ucl": api["ucl"], "chart-lcl": api["lcl"],
               "chart-usl": 10.0, "chart-lsl": -10.0}
    for cls, value in on_axis.items():
        line_ = got["lines"][cls]
        assert line_ is not None, f"no {cls} line"
        assert line_["value"] == pytest.approx(value)
        assert line_["y"] == pytest.approx(y0 + (value - v0) * (y1 - y0) / (v1 - v0), abs=0.5)
    assert any(s.startswith("USL 10") for s in got["labels"])
    assert any(s.startswith("UCL ") for s in got["labels"])
    xt = got["xticks"]
    assert len(xt) >= 3 and all(a["x"] < b["x"] for a, b in zip(xt, xt[1:], strict=False))
    for t in xt:
        started = api["points"][t["i"]]["started_utc"]
        assert t["label"] == f"{started[5:10]} {started[11:16]}"
        assert re.fullmatch(r"\d\d-\d\d \d\d:\d\d", t["label"])
