"""The line dashboard's control chart and Cpk (issue 26, finding 11): the chart carries its
units, centre and control limits, and its axis labels (line.js, run in chromium) are round values
with the digits their step needs; Cpk is "too few" below the minimum number of values."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from playwright.sync_api import Page

from reports.lot_stats import MIN_CPK_N
from station.db.connect import dispose_all
from station.line.spc import capability
from station.results_db import ResultsDB
from tests.linedb.linekit import line_app, line_client, line_runs

LINE_JS = Path(__file__).resolve().parents[2] / "station" / "line" / "static" / "line.js"


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    db = ResultsDB(tmp_path / "line.sqlite")
    work = line_runs(20, ["EOL-A", "EOL-B"], root=tmp_path / "runs")
    db.add_records([(r.folder, r.record) for r in work])
    with line_client(line_app(db.engine)) as c:
        yield c
    dispose_all()


def test_chart_has_units_centre_and_control_limits(client: TestClient) -> None:
    chart = client.get("/api/chart", params={"coefficient": "bias_dps"}).json()
    assert chart["units"] == "deg/s"
    assert chart["ucl"] == pytest.approx(chart["centre"] + 3 * chart["sigma"])
    assert chart["lcl"] == pytest.approx(chart["centre"] - 3 * chart["sigma"])
    assert chart["sigma"] > 0 and chart["points"]


def test_cpk_is_too_few_below_the_minimum(client: TestClient) -> None:
    caps = client.get("/api/capability").json()["capability"]
    assert caps and all(c["n"] < MIN_CPK_N for c in caps)  # 20 runs, fewer per condition
    assert all(c["too_few"] and c["cpk"] is None and c["ci_low"] is None for c in caps)
    small = capability(2, 0.0, 0.001, -1.0, 1.0)  # the dashboard's Cpk 182 at n = 2
    assert small.too_few and small.cpk is None
    enough = capability(MIN_CPK_N, 0.0, 0.1, -1.0, 1.0)
    assert not enough.too_few and enough.cpk == pytest.approx(1 / 0.3)


def _run_js(page: Page, functions: list[str], expression: str) -> object:
    source = LINE_JS.read_text(encoding="utf-8")
    parts = []
    for name in functions:
        m = re.search(rf"^function {name}\(.*?^\}}$", source, re.S | re.M)
        assert m, f"line.js has no {name}()"
        parts.append(m.group(0))
    return page.evaluate("() => {" + "\n".join(parts) + f"\nreturn {expression}; }}")


def test_axis_ticks_are_round_values_with_readable_labels(page: Page) -> None:
    got = _run_js(page, ["niceTicks", "tickLabel"],
                  "[[-0.013, 0.021], [0.9987, 1.0031], [-250, 250], [-0.0004, 0.0003]]"
                  ".map(([lo, hi]) => {"
                  " const t = niceTicks(lo, hi, 5);"
                  " return t.map((v) => tickLabel(v, t[1] - t[0])); })")
    assert got == [["-0.01", "0", "0.01", "0.02"],
                   ["0.999", "1", "1.001", "1.002", "1.003"],
                   ["-200", "-100", "0", "100", "200"],
                   ["-4e-4", "-2e-4", "0", "2e-4"]]
    assert not any(re.fullmatch(r"-0(\.0*)?", label) for row in got for label in row)
