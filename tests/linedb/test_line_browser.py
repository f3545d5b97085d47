"""The line's dashboard in a real browser (Playwright + Debian's chromium) over several
hundred runs from four stations: the yields, first-pass yields and Cpk it shows equal a
direct computation from the records; a certificate opens from its run folder, and a
certificate that cannot be reached says so."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from procedures.runtime.record import CERTIFICATE_FILE
from station.db.connect import dispose_all
from station.line.spc import capability
from station.results_db import ResultsDB
from station.ui.server import serve_in_thread
from tests.linedb.linekit import direct_yields, line_app, line_runs, sign_in_page

STATIONS = ["EOL-A", "EOL-B", "EOL-C", "EOL-D"]


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, list[Any]]]:
    folder = tmp_path_factory.mktemp("line")
    work = line_runs(400, STATIONS, seed=3, root=folder / "runs")
    db = ResultsDB(folder / "central.sqlite")
    db.add_records([(r.folder, r.record) for r in work])
    with_pdf = work[-1].folder
    with_pdf.mkdir(parents=True)
    (with_pdf / CERTIFICATE_FILE).write_bytes(b"%PDF-1.4\n% test certificate\n%%EOF\n")
    server = serve_in_thread(line_app(db.engine))
    try:
        yield server.url, [r.record for r in work]
    finally:
        server.stop()
        dispose_all()


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


@pytest.fixture
def dashboard(line: tuple[str, list[Any]], page: Any) -> Any:
    sign_in_page(page, line[0])
    return page


def test_yields_shown_equal_a_direct_count(line: tuple[str, list[Any]], dashboard: Any) -> None:
    _, records = line
    (units, tests, fp, final), = direct_yields(records, lambda r: "all").values()
    assert len(records) >= 400 and tests > units
    box = dashboard.locator("#yield-all")
    assert box.get_attribute("data-fpy") == _pct(fp / units)
    assert box.get_attribute("data-final") == _pct(final / units)
    assert f"{units} units, {tests} tests" in box.inner_text()
    by_station = direct_yields(records, lambda r: r.station["id"])
    for sid in STATIONS:
        row = dashboard.locator(f'#yields tr[data-group="{sid}"]')
        u, t, f, fin = by_station[sid]
        assert row.locator("td").nth(1).inner_text() == str(u)
        assert row.locator("td.fpy").inner_text() == _pct(f / u)
        assert row.locator("td.final").inner_text() == _pct(fin / u)
    dashboard.click('#yield-tabs button[data-group="lot"]')
    by_lot = direct_yields(records, lambda r: r.lot)
    assert dashboard.locator("#yields tbody tr").count() == len(by_lot)
    row = dashboard.locator('#yields tr[data-group="LOT-003"]')
    u, _, f, _ = by_lot["LOT-003"]
    assert row.locator("td.fpy").inner_text() == _pct(f / u)


def test_cpk_shown_equals_numpy(line: tuple[str, list[Any]], dashboard: Any) -> None:
    _, records = line
    firsts: dict[str, Any] = {}
    for r in sorted(records, key=lambda r: (r.started_utc, r.run_id)):
        firsts.setdefault(r.dut.serial, r)
    values = np.array([m.value for r in firsts.values() for m in r.measurements
                       if m.name == "bias_dps" and m.value is not None])
    m0 = next(m for m in records[0].measurements if m.name == "bias_dps")
    cap = capability(len(values), float(values.mean()), float(values.std(ddof=1)), m0.low,
                     m0.high)
    assert cap.cpk is not None and cap.ci_low is not None and cap.ci_high is not None
    row = dashboard.locator('#capability tr[data-name="bias_dps"]')
    assert row.locator("td.cpk").inner_text() == f"{cap.cpk:.2f}"
    assert row.locator("td.ci").inner_text() == f"{cap.ci_low:.2f} – {cap.ci_high:.2f}"
    assert "Bissell" in dashboard.locator("#cpk-note").inner_text()


def test_stations_chart_and_certificates(line: tuple[str, list[Any]], dashboard: Any) -> None:
    url, records = line
    assert dashboard.locator("#stations .card").count() == len(STATIONS)
    assert dashboard.locator("#chart circle").count() == 200
    last = max(records, key=lambda r: r.started_utc)
    link = dashboard.locator(f'#runs tr[data-run="{last.run_id}"] a')
    assert link.get_attribute("href") == f"/certificate/{last.run_id}"
    r = dashboard.request.get(url + f"/certificate/{last.run_id}")
    assert r.status == 200 and r.body().startswith(b"%PDF")
    other = records[0].run_id
    r = dashboard.request.get(url + f"/certificate/{other}")
    assert r.status == 404 and "not reachable from here" in r.json()["error"]
